"""Which pixels lie inside any of a set of image ellipses: numpy, or compiled (numba).

The silhouette limb search (:mod:`core.silhouette_search`) scores every grid hypothesis
of a limb by the foreground pixels its projected ellipsoids cover.  A pixel ``u`` is
inside ellipse ``e`` when ``(u − μ_e)ᵀ S_e (u − μ_e) ≤ 1`` (``S_e`` the inverse shape,
:func:`core.silhouette_search.image_ellipses`; an all-zero ``S_e`` marks an ellipsoid
behind the camera, which covers nothing).  The numpy path builds (H, E, G) temporaries
for H hypotheses, E ellipses and G pixels, and was the fit's largest single cost on
make demo's walk (41 s of 300); the compiled path loops and stops at the first ellipse
that covers a pixel.  Both evaluate the quadratic form in the same order, so they agree
bit for bit.

Optional at run time like :mod:`core.field_kernel` (whose :func:`~core.field_kernel.run`
and :func:`~core.field_kernel.enabled` it shares): without numba, with
``SOMACAP_NO_NUMBA=1``, or after a failed first compile, the numpy path runs.
"""

from __future__ import annotations

import numpy as np

from .field_kernel import enabled, run
from .lsm_kernel_jit import jit


def covered(uv: np.ndarray, mu: np.ndarray, inv: np.ndarray) -> np.ndarray:
    """(..., G) bool: pixels ``uv`` (G, 2) inside any of the ellipses (..., E).

    Parameters
    ----------
    uv : (G, 2) pixel positions, px
    mu : (..., E, 2) ellipse centres, px
    inv : (..., E, 2, 2) inverse shapes, 1/px² (all zero: an ellipse that covers nothing)
    """
    uv = np.asarray(uv, float).reshape(-1, 2)
    mu, inv = np.asarray(mu, float), np.asarray(inv, float)
    lead = mu.shape[:-2]
    E = mu.shape[-2]
    if enabled() and E and len(uv):
        out = np.zeros((int(np.prod(lead, dtype=int)), len(uv)), bool)
        args = (
            np.ascontiguousarray(uv),
            np.ascontiguousarray(mu.reshape(-1, E, 2)),
            np.ascontiguousarray(inv.reshape(-1, E, 2, 2)),
            out,
        )
        if run(_covered_loops, *args):
            return out.reshape(lead + (len(uv),))
    return covered_numpy(uv, mu, inv)


def covered_numpy(uv: np.ndarray, mu: np.ndarray, inv: np.ndarray) -> np.ndarray:
    """:func:`covered` with numpy arrays over (..., E, G): the reference."""
    du = uv[:, 0] - mu[..., 0, None]  # (..., E, G)
    dv = uv[:, 1] - mu[..., 1, None]
    q = (
        inv[..., 0, 0, None] * du * du
        + 2.0 * inv[..., 0, 1, None] * du * dv
        + inv[..., 1, 1, None] * dv * dv
    )
    live = np.any(inv != 0, axis=(-1, -2))[..., None]  # (..., E, 1)
    return np.any((q <= 1.0) & live, axis=-2)


@jit()
def _covered_loops(uv, mu, inv, out):  # pragma: no cover - compiled
    """:func:`covered_numpy` as loops over hypotheses, pixels and ellipses; fills out."""
    H, E = mu.shape[0], mu.shape[1]
    live = np.empty(E, np.bool_)
    for h in range(H):
        for e in range(E):
            live[e] = (
                inv[h, e, 0, 0] != 0.0
                or inv[h, e, 0, 1] != 0.0
                or inv[h, e, 1, 0] != 0.0
                or inv[h, e, 1, 1] != 0.0
            )
        for g in range(uv.shape[0]):
            for e in range(E):
                if not live[e]:
                    continue
                du = uv[g, 0] - mu[h, e, 0]
                dv = uv[g, 1] - mu[h, e, 1]
                q = (
                    inv[h, e, 0, 0] * du * du
                    + 2.0 * inv[h, e, 0, 1] * du * dv
                    + inv[h, e, 1, 1] * dv * dv
                )
                if q <= 1.0:
                    out[h, g] = True
                    break
