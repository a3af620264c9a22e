"""Log field of all metaballs at many points, for many poses: numpy, or compiled (numba).

:func:`log_field` is the inner loop of the fit's global search (:mod:`core.fit_search`):
every grid hypothesis of a limb scores the frame's points and their lines of sight
against the whole body, ``L = ln Σ_m exp(−2 d_m)`` and ``∇L``.  The numpy path builds
(H, M, N, 3) temporaries (a few hundred MB for a limb's grid on the dance scene) and was
40 % of the fit's time there; the compiled path loops over poses and points and keeps
one point's M terms (same formula, same log-sum-exp shift by the largest term).  The
two agree to ~1e-13 (sums in a different order).

:func:`inside_any` (is a point inside any ellipsoid) serves the model's occluding contour
(:mod:`core.model_contours`) the same way: compiled, it stops at the first ellipsoid
found around a point.

Optional at run time as :mod:`core.lsm_kernel`: without numba (the Blender add-on does
not bundle it), with ``SOMACAP_NO_NUMBA=1``, or after a failed first compile, the numpy
path runs.
"""

from __future__ import annotations

import warnings

import numpy as np

from .lsm_kernel_jit import env_off, jit, numba

_FAILED = {"error": None}


def enabled() -> bool:
    """Whether :func:`log_field` runs compiled (numba imported, its first compile did
    not fail, ``SOMACAP_NO_NUMBA`` not set to a true value now)."""
    return numba is not None and _FAILED["error"] is None and not env_off()


def run(kernel, *args) -> bool:
    """Call a compiled kernel of the fit (this module's or :mod:`core.attractor_kernel`'s)
    with numba's warnings silenced.  Returns False — and switches the compiled paths off
    for the process (:func:`enabled`) — when it raises (a compile that fails on this
    machine); the caller then runs its numpy path."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            kernel(*args)
        return True
    except Exception as err:  # pragma: no cover - a broken numba
        _FAILED["error"] = f"{type(err).__name__}: {err}"
        return False


def log_field(
    xyz: np.ndarray, Rw: np.ndarray, cw: np.ndarray, radii: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Log field ``L = ln Σ_m exp(−2 d_m)`` of H poses' metaballs at N points, and its
    gradient (eq. 7–8 of the first paper, as a log-sum-exp).

    Parameters
    ----------
    xyz : (N, 3) world points, metres
    Rw : (H, M, 3, 3) metaball axes in world (columns), per pose
    cw : (H, M, 3) metaball centres, world metres
    radii : (M, 3) semi-axes, metres

    Returns
    -------
    L : (H, N); grad : (H, N, 3) world ``∇L``, 1/metre
    """
    xyz = np.ascontiguousarray(xyz, dtype=float).reshape(-1, 3)
    Rw = np.ascontiguousarray(Rw, dtype=float)
    cw = np.ascontiguousarray(cw, dtype=float)
    inv_r2 = np.ascontiguousarray(1.0 / np.asarray(radii, float) ** 2)
    H, M = Rw.shape[:2]
    if enabled() and M:
        L = np.empty((H, len(xyz)))
        g = np.empty((H, len(xyz), 3))
        if run(_log_field_loops, xyz, Rw, cw, inv_r2, L, g):
            return L, g
    return log_field_numpy(xyz, Rw, cw, radii)


def log_field_numpy(xyz, Rw, cw, radii) -> tuple[np.ndarray, np.ndarray]:
    """:func:`log_field` with numpy arrays over (H, M, N, 3): the reference."""
    y = (np.asarray(xyz, float)[None, None] - cw[:, :, None]) @ Rw  # (H, M, N, 3) local
    q = y / np.asarray(radii, float)[None, :, None] ** 2
    e = -2.0 * np.sum(y * q, axis=-1)  # (H, M, N)
    top = e.max(axis=1, keepdims=True)
    w = np.exp(e - top)
    tot = w.sum(axis=1)
    L = top[:, 0] + np.log(tot)
    g = -4.0 * np.einsum("hmn,hmnk->hnk", w, q @ np.swapaxes(Rw, -1, -2)) / tot[..., None]
    return L, g


@jit()
def _log_field_loops(xyz, Rw, cw, inv_r2, L, g):  # pragma: no cover - compiled
    """:func:`log_field_numpy` as loops over poses, points and metaballs; fills L, g."""
    H, M = Rw.shape[0], Rw.shape[1]
    e = np.empty(M)
    gm = np.empty((M, 3))
    for h in range(H):
        for n in range(xyz.shape[0]):
            top = -np.inf
            for m in range(M):
                d0 = xyz[n, 0] - cw[h, m, 0]
                d1 = xyz[n, 1] - cw[h, m, 1]
                d2 = xyz[n, 2] - cw[h, m, 2]
                R = Rw[h, m]
                y0 = d0 * R[0, 0] + d1 * R[1, 0] + d2 * R[2, 0]
                y1 = d0 * R[0, 1] + d1 * R[1, 1] + d2 * R[2, 1]
                y2 = d0 * R[0, 2] + d1 * R[1, 2] + d2 * R[2, 2]
                q0 = y0 * inv_r2[m, 0]
                q1 = y1 * inv_r2[m, 1]
                q2 = y2 * inv_r2[m, 2]
                em = -2.0 * (y0 * q0 + y1 * q1 + y2 * q2)
                e[m] = em
                gm[m, 0] = q0 * R[0, 0] + q1 * R[0, 1] + q2 * R[0, 2]
                gm[m, 1] = q0 * R[1, 0] + q1 * R[1, 1] + q2 * R[1, 2]
                gm[m, 2] = q0 * R[2, 0] + q1 * R[2, 1] + q2 * R[2, 2]
                if em > top:
                    top = em
            tot = 0.0
            s0 = s1 = s2 = 0.0
            for m in range(M):
                w = np.exp(e[m] - top)
                tot += w
                s0 += w * gm[m, 0]
                s1 += w * gm[m, 1]
                s2 += w * gm[m, 2]
            L[h, n] = top + np.log(tot)
            g[h, n, 0] = -4.0 * s0 / tot
            g[h, n, 1] = -4.0 * s1 / tot
            g[h, n, 2] = -4.0 * s2 / tot


def inside_any(
    xyz: np.ndarray, A: np.ndarray, centers: np.ndarray, exclude: np.ndarray, limit: float
) -> np.ndarray:
    """Whether each point lies inside any ellipsoid but its excluded one, (N,) bool.

    Parameters
    ----------
    xyz : (N, 3) world points, metres
    A : (E, 3, 3) world -> unit-sphere maps of the ellipsoids (``axesᵀ / radii``)
    centers : (E, 3) metres
    exclude : (N,) int, one ellipsoid index per point not to test (−1: none)
    limit : a point is inside where ``|A (x − c)|² < limit``
    """
    xyz = np.ascontiguousarray(xyz, dtype=float).reshape(-1, 3)
    A = np.ascontiguousarray(A, dtype=float)
    centers = np.ascontiguousarray(centers, dtype=float)
    exclude = np.ascontiguousarray(exclude, dtype=np.int64)
    if enabled():
        out = np.zeros(len(xyz), dtype=np.bool_)
        if run(_inside_any_loops, xyz, A, centers, exclude, float(limit), out):
            return out
    q = (xyz[None, :, :] - centers[:, None, :]) @ np.swapaxes(A, 1, 2)  # (E, N, 3)
    inside = np.sum(q * q, axis=-1) < limit
    own = exclude >= 0
    inside[exclude[own], np.flatnonzero(own)] = False
    return inside.any(axis=0)


@jit()
def _inside_any_loops(xyz, A, centers, exclude, limit, out):  # pragma: no cover - compiled
    for n in range(xyz.shape[0]):
        for e in range(A.shape[0]):
            if e == exclude[n]:
                continue
            d0 = xyz[n, 0] - centers[e, 0]
            d1 = xyz[n, 1] - centers[e, 1]
            d2 = xyz[n, 2] - centers[e, 2]
            u0 = A[e, 0, 0] * d0 + A[e, 0, 1] * d1 + A[e, 0, 2] * d2
            u1 = A[e, 1, 0] * d0 + A[e, 1, 1] * d1 + A[e, 1, 2] * d2
            u2 = A[e, 2, 0] * d0 + A[e, 2, 1] * d1 + A[e, 2, 2] * d2
            if u0 * u0 + u1 * u1 + u2 * u2 < limit:
                out[n] = True
                break
