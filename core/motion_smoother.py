"""The fitted motion smoothed over the whole take: a fixed-interval Kalman smoother.

The sequence fit solves frame after frame, each frame from the prediction of the last
ones and its own observations (the second paper's filter, run forward only).  Once
every frame is fitted, each frame's angles can also learn from the frames after it:
:func:`smooth_angles` runs, for every degree of freedom on its own, a Kalman filter
forward and a Rauch–Tung–Striebel pass backward with a constant-velocity model (white
acceleration), which is the cubic smoothing spline of that angle over time.

How smooth is not set by hand: the ratio of the process noise (the acceleration's
variance) to the fit's frame-to-frame noise is the one that makes the take most likely
(the filters' innovations, each series' measurement variance concentrated out: the
generalised maximum likelihood choice of a smoothing spline's parameter).  For the
motion it is one ratio for every angle and the root, from the sum of their likelihoods,
so that the smoother is one linear operator over time for all of them (but for the
down-weighted frames below): angles that trade off along a chain (the spine's links, a
shoulder against its clavicle) keep their sum's path.  Each angle with its own ratio
broke that (make demo's walk, exact clicks: head 3.9 → 9.1 mm, MPJPE 9.93 → 11.06 mm;
one ratio: 9.92 mm).  Frames marked diverged are not used and keep their values; a frame
far off the smoothed path (a one-frame flip) is down-weighted in a few reweighted passes
(Cauchy weights on the residuals).  Angles are kept within their joint limits.

What one smoothness costs: where a single limb moves fast and the rest of the body is
still, the still angles outvote it (each gains a little from smoothing, the kicked one
loses much), and the kick is spread over its neighbours.  Letting a series whose own
smoothness is far more likely (by 10 nats) keep it frees a kick only in longer takes
(30 frames: 0.80 → 0.24 rad off at the kick, 7 frames: none) and breaks the walk's
spine again (MPJPE 9.93 → 10.95 mm); a kick is a step, which no constant-velocity
smoother follows.  The sequence fit therefore gives the smoothed values by default only
to the angles no observation decided (``SequenceSettings.smooth_unobserved``: a hidden
limb's filled angles, whose jitter is most of the fit's).

:func:`smooth_joints`, the sequence fit's opt-in (``SequenceSettings.smooth_motion``,
``core fit --smooth``; the figures are there), smooths where the motion is seen: each
joint's world path with its own smoothness, then the angles solved to the smoothed
joints.  A chain's trade-offs cannot wobble its end (the ends are what is smoothed),
and a fast limb is not outvoted by still ones; on every take measured its jitter is
lower than with one smoothness for every angle.  A step is still spread.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: The ratios tried: the white acceleration's intensity (units² per frame³) over the
#: measurement variance (units²).
RATIOS = 10.0 ** np.linspace(-7.0, 2.0, 37)

_A = np.array([[1.0, 1.0], [0.0, 1.0]])
_Q = np.array([[1.0 / 3.0, 0.5], [0.5, 1.0]])


@dataclass
class Smoothed:
    """What :func:`smooth_series` returns.

    Attributes
    ----------
    x : ndarray, shape (F, K)
        The smoothed series (the input where a frame was not used).
    ratio : ndarray, shape (K,)
        The chosen process-to-measurement noise ratio of each series.
    noise : ndarray, shape (K,)
        The measurement noise's standard deviation the smoother estimated, the series'
        units (NaN where fewer than 4 frames were used).
    far : ndarray, shape (F, K), bool
        Frames more than ``cauchy_c`` estimated σ off the smoothed path (down-weighted
        to less than half).
    """

    x: np.ndarray
    ratio: np.ndarray
    noise: np.ndarray
    far: np.ndarray


def _filter(z, use, ratio, var):
    """Kalman filter of G × K series at once.

    ``z`` (F, K), ``use`` (F, K) bool, ``ratio`` (G, K) process over measurement noise,
    ``var`` (F, K) relative measurement variances.  Returns the predicted and filtered
    means and covariances, (F, G, K, 2[, 2]), and the concentrated log-likelihood
    (G, K) with the measurement variance per series (G, K).
    """
    f, k = z.shape
    g = ratio.shape[0]
    xp = np.zeros((f, g, k, 2))
    pp = np.zeros((f, g, k, 2, 2))
    xf = np.zeros((f, g, k, 2))
    pf = np.zeros((f, g, k, 2, 2))
    x = np.zeros((g, k, 2))
    p = np.broadcast_to(np.eye(2) * 1e8, (g, k, 2, 2)).copy()
    first = np.argmax(use, axis=0)
    x[..., 0] = z[first, np.arange(k)]
    seen = np.zeros(k, int)
    sum_log = np.zeros((g, k))
    sum_e2 = np.zeros((g, k))
    n_lik = np.zeros(k)
    q = ratio[..., None, None] * _Q
    for t in range(f):
        if t > 0:
            x = x @ _A.T
            p = _A @ p @ _A.T + q
        xp[t], pp[t] = x, p
        u = use[t]
        if u.any():
            s = p[..., 0, 0] + var[t]
            gain = p[..., :, 0] / s[..., None]
            e = z[t] - x[..., 0]
            upd = u[None, :, None]
            x = np.where(upd, x + gain * e[..., None], x)
            p = np.where(
                upd[..., None], p - gain[..., :, None] * gain[..., None, :] * s[..., None, None], p
            )
            lik = u & (seen >= 2)  # the first two frames start the diffuse state
            sum_log += np.where(lik, np.log(s), 0.0)
            sum_e2 += np.where(lik, e * e / s, 0.0)
            n_lik += lik
            seen += u
        xf[t], pf[t] = x, p
    n = np.maximum(n_lik, 1.0)
    r = sum_e2 / n
    with np.errstate(divide="ignore"):
        ll = -0.5 * (sum_log + n * np.log(np.maximum(r, 1e-300)))
    return xp, pp, xf, pf, ll, r


def _smooth(xp, pp, xf, pf):
    """Rauch–Tung–Striebel pass over the filter's output: the smoothed means (F, K, 2)."""
    xs = xf.copy()
    for t in range(xf.shape[0] - 2, -1, -1):
        c = pf[t] @ _A.T @ np.linalg.inv(pp[t + 1])
        xs[t] = xf[t] + np.einsum("...ij,...j->...i", c, xs[t + 1] - xp[t + 1])
    return xs


def smooth_series(
    z: np.ndarray,
    use: np.ndarray,
    *,
    ratios: np.ndarray = RATIOS,
    passes: int = 3,
    cauchy_c: float = 3.0,
    common: bool = False,
) -> Smoothed:
    """Smooth K series over F frames by their maximum-likelihood smoothness (each its
    own, or one for all).

    Parameters
    ----------
    z : ndarray, shape (F, K)
        The series (any units; one column per series).
    use : ndarray, shape (F, K), bool
        Frames that are measurements; the others are bridged by the model but keep
        their values in the output.
    ratios : ndarray, shape (G,)
        Process-to-measurement noise ratios to choose from, per frame³.
    passes : int
        Reweighted passes: after each, frames whose residual exceeds the estimated
        noise get the Cauchy weight ``1 / (1 + (u / cauchy_c)²)`` (1: no reweighting).
    cauchy_c : float
        Scale of the Cauchy weights, in estimated noise σ.
    common : bool
        One ratio for all series (the largest sum of their log-likelihoods), else each
        series its own.

    Returns
    -------
    Smoothed
    """
    z = np.asarray(z, float)
    use = np.asarray(use, bool) & np.isfinite(z)
    f, k = z.shape
    out = Smoothed(
        x=z.copy(), ratio=np.full(k, np.nan), noise=np.full(k, np.nan), far=np.zeros((f, k), bool)
    )
    cols = np.flatnonzero(use.sum(axis=0) >= 4)
    if f < 4 or len(cols) == 0:
        return out
    zc, uc = np.where(use[:, cols], z[:, cols], 0.0), use[:, cols]
    var = np.ones(zc.shape)
    grid = np.repeat(np.asarray(ratios, float)[:, None], len(cols), axis=1)
    for _ in range(max(1, passes)):
        _, _, _, _, ll, r = _filter(zc, uc, grid, var)
        best = np.argmax(ll, axis=0)
        if common:  # one ratio for all series: the sum of their likelihoods
            best = np.full(len(cols), np.argmax(ll.sum(axis=1)))
        pick = np.arange(len(cols))
        ratio, noise_var = grid[best, pick], r[best, pick]
        xp, pp, xf, pf, _, _ = _filter(zc, uc, ratio[None], var)
        xs = _smooth(xp[:, 0], pp[:, 0], xf[:, 0], pf[:, 0])
        resid = (zc - xs[..., 0]) / np.sqrt(np.maximum(noise_var, 1e-300))
        var = np.where(uc, 1.0 + (resid / cauchy_c) ** 2, 1.0)
    sm = xs[..., 0]
    out.x[:, cols] = np.where(uc, sm, z[:, cols])
    out.ratio[cols] = ratio
    out.noise[cols] = np.sqrt(noise_var)
    out.far[:, cols] = uc & (np.abs(resid) > cauchy_c)
    return out


def smooth_angles(
    theta: np.ndarray,
    root_xyz: np.ndarray,
    diverged: np.ndarray,
    lo: np.ndarray | None = None,
    hi: np.ndarray | None = None,
    **kwargs,
) -> tuple[np.ndarray, np.ndarray, Smoothed]:
    """The fitted angles and root position smoothed over the take (see the module text).

    Parameters
    ----------
    theta : ndarray, shape (F, n)
        Joint angles, radians (unwrapped over time before smoothing, so a turn past
        ±π is one motion).
    root_xyz : ndarray, shape (F, 3)
        Root position, metres.
    diverged : ndarray, shape (F,), bool
        Frames not used (and left as they are).
    lo, hi : ndarray, shape (n,), optional
        Joint limits, radians (±inf: none).  A smoothed angle is kept within them, or
        within its own frame's value where the fit itself went past a (soft) limit.
    **kwargs
        Passed to :func:`smooth_series` (``common`` defaults to True here).

    Returns
    -------
    theta, root_xyz : ndarray, shapes (F, n) and (F, 3)
        Smoothed copies.
    smoothed : Smoothed
        Per series (the n angles, then x, y, z of the root): the chosen ratios and
        estimated noise.
    """
    theta = np.asarray(theta, float)
    root_xyz = np.asarray(root_xyz, float)
    f, n = theta.shape
    unwrapped = np.unwrap(theta, axis=0) if f > 1 else theta.copy()
    z = np.concatenate([unwrapped, root_xyz], axis=1)
    use = np.repeat(~np.asarray(diverged, bool)[:, None], n + 3, axis=1)
    res = smooth_series(z, use, **{"common": True, **kwargs})
    th = res.x[:, :n] - unwrapped + theta  # the frames' own branch of each angle
    if lo is not None:
        th = np.maximum(th, np.minimum(np.asarray(lo, float)[None], theta))
    if hi is not None:
        th = np.minimum(th, np.maximum(np.asarray(hi, float)[None], theta))
    return th, res.x[:, n:], res


def smooth_joints(
    skel,
    s: np.ndarray,
    theta: np.ndarray,
    root_xyz: np.ndarray,
    diverged: np.ndarray,
    *,
    hold: float = 1e-3,
    iterations: int = 6,
    **kwargs,
) -> tuple[np.ndarray, np.ndarray, Smoothed]:
    """The motion smoothed where it is seen: each joint's world position over the take,
    then the angles and root that put the joints there.

    Every coordinate of every joint of the skeleton is its own series, with its own
    maximum-likelihood smoothness (:func:`smooth_series`): a kicked ankle keeps its
    kick while a still head is smoothed, and a chain's links that trade off against
    each other cannot wobble its end, since the ends themselves are smoothed.  The
    angles and root are then solved, frame by frame (Gauss–Newton, all frames at
    once), to put the skeleton's joints at the smoothed places, each angle held
    towards its fitted value with weight ``hold`` (m² per rad²: what the joints do not
    decide, a twist, stays as fitted).

    Parameters
    ----------
    skel : core.skeleton.Skeleton
    s : ndarray, shape (G,)
        Scale coefficients.
    theta, root_xyz, diverged :
        As :func:`smooth_angles`; the angles are kept within the skeleton's limits the
        same way.
    hold : float
        Weight of each angle's pull towards its fitted value, m² per rad².
    iterations : int
        Gauss–Newton iterations.
    **kwargs
        Passed to :func:`smooth_series`.

    Returns
    -------
    theta, root_xyz : ndarray, shapes (F, n) and (F, 3)
    smoothed : Smoothed
        Per joint coordinate (J × 3 series, joint-major).
    """
    from .skeleton import joint_jacobians, joint_positions

    theta0 = np.asarray(theta, float)
    root0 = np.asarray(root_xyz, float)
    div = np.asarray(diverged, bool)
    f, n = theta0.shape
    x = joint_positions(skel, theta0, root0, s)  # (F, J, 3)
    nj = x.shape[1]
    res = smooth_series(x.reshape(f, nj * 3), np.repeat(~div[:, None], nj * 3, axis=1), **kwargs)
    target = res.x.reshape(f, nj, 3)
    th, rt = theta0.copy(), root0.copy()
    eye = np.tile(np.eye(3), (nj, 1))  # ∂x/∂root, (3J, 3)
    reg = np.r_[np.full(n, hold), np.zeros(3)]
    for _ in range(iterations):
        xx, jac, _ = joint_jacobians(skel, th, rt, s)
        a = np.concatenate([jac.reshape(f, nj * 3, n), np.broadcast_to(eye, (f, nj * 3, 3))], 2)
        r = (xx - target).reshape(f, nj * 3)
        h = np.einsum("fki,fkj->fij", a, a) + np.diag(reg)[None]
        g = np.einsum("fki,fk->fi", a, r)
        g[:, :n] += hold * (th - theta0)
        step = -np.linalg.solve(h, g[..., None])[..., 0]
        th, rt = th + step[:, :n], rt + step[:, n:]
    th = np.clip(th, np.minimum(skel.dof_lo, theta0), np.maximum(skel.dof_hi, theta0))
    th[div], rt[div] = theta0[div], root0[div]
    return th, rt, res
