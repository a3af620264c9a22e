"""The metaball body's whole surface: points on it, the ellipsoids that render it, and the
deflated template whose blend follows them.

The iso-surface ``F(x) = Σ_m f_m(x) = 0.5`` of :mod:`core.metaballs` has no closed form
where metaballs overlap.  :func:`project_to_surface` walks points onto it by Newton
steps; :func:`sample_surface` spreads points over a frame's whole body (evaluation,
tests); :func:`render_radii` fits, per metaball, the ellipsoid whose union approximates
the blend (what the splatting renderers draw); :func:`deflate` shrinks a template so
that its blend follows its lone ellipsoids instead of swelling where they overlap.
All lengths in metres, all points in the world frame.
"""

from __future__ import annotations

import numpy as np

from .metaballs import (
    THRESHOLD,
    VISIBLE,
    Metaballs,
    field,
    local_coords,
    one_frame,
    world_frames,
)
from .skeleton import Pose, Skeleton, forward
from .vec3 import sum3


def project_to_surface(
    x: np.ndarray,
    Rw: np.ndarray,
    cw: np.ndarray,
    radii: np.ndarray,
    iterations: int = 30,
    tol: float = 1e-9,
):
    """Move points onto the iso-surface ``F = 0.5`` by Newton steps along the gradient.

    Each point stops once it is within ``tol`` of the surface (or has no usable
    gradient), after at most ``iterations`` steps: most settle in 4–6, and the field is
    evaluated only at the points still moving.

    Parameters
    ----------
    x : (N, 3) start points (e.g. samples around the body)

    Returns
    -------
    xs : (N, 3) projected points
    ok : (N,) bool — converged to ``|F − 0.5| < tol`` with a usable gradient
    """
    x = np.array(x, dtype=float)
    F = np.full(len(x), np.inf)
    gg = np.zeros(len(x))
    active = np.arange(len(x))  # points still moving; the others are settled
    for _ in range(iterations):
        if not len(active):
            break
        Fa, g, _, _ = field(x[active], Rw, cw, radii)
        F[active], gg[active] = Fa, sum3(g * g)
        r = Fa - THRESHOLD
        # settled: on the surface, or without a usable gradient (a zero step for good)
        moving = (np.abs(r) >= tol) & (gg[active] > 1e-12)
        active, r, g = active[moving], r[moving], g[moving]
        step = r / gg[active]
        # limit the step to 5 cm so that far points walk in safely
        norm = np.sqrt(gg[active]) * np.abs(step)
        step = step * np.minimum(1.0, 0.05 / np.maximum(norm, 1e-300))
        x[active] -= step[:, None] * g
    if len(active):  # moved by the last step: evaluate where they landed
        Fa, g, _, _ = field(x[active], Rw, cw, radii)
        F[active], gg[active] = Fa, sum3(g * g)
    ok = (np.abs(F - THRESHOLD) < tol) & (gg > 1e-12)
    return x, ok


def sample_surface(
    skel: Skeleton,
    pose: Pose,
    balls: Metaballs,
    s: np.ndarray,
    per_ball: int = 200,
    frame: int = 0,
    seed: int = 0,
):
    """Points on the whole-body surface of one frame (for evaluation and tests).

    Starts from points on each metaball's lone visible ellipsoid and projects them by
    :func:`project_to_surface`.  Returns ``(xyz (N, 3), ok (N,) bool)``.
    """
    rng = np.random.default_rng(seed)
    Rw, cw = world_frames(skel, one_frame(pose, frame), balls, s)
    Rw, cw = Rw[0], cw[0]
    u = rng.normal(size=(len(balls), per_ball, 3))
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    local = u * balls.radii[:, None, :] * VISIBLE
    x0 = np.einsum("mij,mpj->mpi", Rw, local) + cw[:, None, :]
    return project_to_surface(x0.reshape(-1, 3), Rw, cw, balls.radii)


def fibonacci_sphere(n: int) -> np.ndarray:
    """``n`` unit vectors (n, 3) spread evenly over the sphere (a Fibonacci lattice)."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = np.pi * (1.0 + 5.0**0.5) * k
    return np.stack([np.sqrt(1 - z**2) * np.cos(phi), np.sqrt(1 - z**2) * np.sin(phi), z], 1)


def render_radii(
    skel: Skeleton,
    pose: Pose,
    balls: Metaballs,
    s: np.ndarray,
    per_ball: int = 64,
    frame: int = 0,
    max_scale: float = 2.0,
) -> np.ndarray:
    """Semi-axes (M, 3) of ellipsoids whose union approximates the blended surface.

    A lone metaball's visible surface is the ellipsoid ``radii · VISIBLE``; where
    metaballs overlap the whole-body iso-surface ``Σ f = 0.5`` lies outside those
    ellipsoids (a fitted shape often keeps its metaballs small and lets the blend
    make the flesh).  Renderers that splat ellipsoids (:mod:`core.model_render`) use
    these instead: points spread over each metaball's lone ellipsoid are projected
    onto the iso-surface (:func:`project_to_surface`), and per metaball the axes
    ``a`` solve ``Σ_k (y_k / a_k)² = 1`` in least squares over those points (``y`` in
    the metaball's frame), each weighted by the metaball's share ``f_m / Σ f`` of the
    field there.  Clipped to ``[1, max_scale]`` times the lone visible axes.

    Parameters
    ----------
    pose : Pose holding frame ``frame``; s : (G,)
    per_ball : points per metaball (a Fibonacci sphere)

    Returns
    -------
    (M, 3) metres.
    """
    Rw, cw = world_frames(skel, one_frame(pose, frame), balls, s)
    Rw, cw = Rw[0], cw[0]
    u = fibonacci_sphere(per_ball)
    lone = balls.radii * VISIBLE
    x0 = np.einsum("mij,mpj->mpi", Rw, u[None] * lone[:, None, :]) + cw[:, None, :]
    xs, ok = project_to_surface(x0.reshape(-1, 3), Rw, cw, balls.radii)
    _, _, f, _ = field(xs, Rw, cw, balls.radii)
    M = len(balls)
    own = np.arange(M).repeat(per_ball)
    share = f[np.arange(len(xs)), own] / np.maximum(f.sum(axis=1), 1e-300)
    w = (share * ok).reshape(M, per_ball)
    y = np.einsum("mji,mpj->mpi", Rw, xs.reshape(M, per_ball, 3) - cw[:, None, :])
    A = y**2  # (M, P, 3): Σ_k A_k u_k = 1 with u_k = 1 / a_k²
    N = np.einsum("mp,mpi,mpj->mij", w, A, A) + 1e-12 * np.eye(3)
    b = np.einsum("mp,mpi->mi", w, A)
    inv2 = np.linalg.solve(N, b[..., None])[..., 0]
    good = np.all(inv2 > 0, axis=1) & (w.sum(axis=1) > 1e-6)
    a = np.where(good[:, None], 1.0 / np.sqrt(np.where(inv2 > 0, inv2, 1.0)), lone)
    return np.clip(a, lone, lone * max_scale)


def deflate(
    skel: Skeleton,
    balls: Metaballs,
    s: np.ndarray,
    per_ball: int = 48,
    iterations: int = 12,
    prior: float = 1.0,
    per_part: bool = True,
) -> Metaballs:
    """Shrink metaballs until their blended surface follows their rendered ellipsoids.

    A template sized so that each lone metaball's iso-surface is the flesh around its
    bone (:func:`make_metaballs`) swells where metaballs overlap: their fields add up
    and ``Σ f = 0.5`` lies outside the lone ellipsoids (the template's whole-body
    surface is ~4 cm off the body).  Here, at the rest pose (θ = 0), points are spread
    over the union of the rendered ellipsoids ``v`` (the input's
    :attr:`Metaballs.visible`; points inside another ellipsoid are left out) and the
    log-radii are fitted by Gauss–Newton so that ``ln Σ f = ln 0.5`` there — with
    ``per_part`` (default), the sums and the unions over the metaballs of the point's own
    body part — (a weak
    prior, σ = ``prior`` in log-radius, towards ``ln(v / VISIBLE)`` keeps buried
    metaballs defined).  ``visible_scale`` is then set to ``v / l``, so the contours,
    the camera selection and the segmentation render the same ellipsoids as before
    while the attractor's blended surface runs along them: one surface for every
    observation type.

    Parameters
    ----------
    skel, balls, s : the skeleton, its metaballs and the scale coefficients (G,)
    per_ball : sample points per rendered ellipsoid (a Fibonacci sphere)
    iterations : Gauss–Newton steps
    prior : σ of the prior on the log-radii
    per_part : each body part deflated on its own (default; the blend still adds up
        across joints), else the whole body at once.  As the start of the whole-body
        shape fit after make demo's motion (in-process, 5 frames, surface against the
        true mesh): per part 25.3 / 22.1 mm on walk_line3 / jumps_line3, whole body
        23.0 / 29.1 mm (not converged on the walk); the template 34.9 / 46.8 mm

    Returns
    -------
    Metaballs with smaller ``radii`` and ``visible_scale`` = ``v / radii``.
    """
    s = np.asarray(s, float)
    pose = forward(skel, np.zeros((1, skel.n_dof)), np.zeros((1, 3)), s)
    Rw, cw = world_frames(skel, pose, balls, s)
    Rw, cw = Rw[0], cw[0]
    v = balls.visible
    M = len(balls)
    u = fibonacci_sphere(per_ball)
    x = (cw[:, None] + np.einsum("mij,mpj->mpi", Rw, u[None] * v[:, None])).reshape(-1, 3)
    y = local_coords(x, Rw, cw)  # (N, M, 3)
    own = np.repeat(np.arange(M), per_ball)
    inside = sum3((y / v[None]) ** 2) < 1.0 - 1e-9
    inside[np.arange(len(x)), own] = False
    if per_part:  # only the metaballs of the point's own part count
        member = balls.bone[own][:, None] == balls.bone[None, :]
        inside &= member
    keep = ~inside.any(axis=1)
    y = y[keep]
    member = member[keep] if per_part else np.ones((len(y), M), bool)
    n = len(y)
    logr0 = np.log(v / VISIBLE)
    logr = logr0.copy()
    for _ in range(iterations):
        q = (y / np.exp(logr)[None]) ** 2  # (n, M, 3)
        f = np.exp(-2.0 * sum3(q)) * member  # (n, M)
        F = np.maximum(f.sum(axis=1), 1e-300)
        r = np.concatenate([np.log(F) - np.log(THRESHOLD), (logr - logr0).ravel() / prior])
        J = np.concatenate(
            [(4.0 * f[..., None] * q / F[:, None, None]).reshape(n, 3 * M), np.eye(3 * M) / prior]
        )
        step = np.linalg.lstsq(J, -r, rcond=None)[0].reshape(M, 3)
        logr = logr + np.clip(step, -0.5, 0.5)
    out = balls.copy(radii=np.exp(logr))
    out.visible_scale = v / out.radii
    return out
