"""Image ellipses of the silhouette limb search: numpy, or compiled (numba).

Three kernels, each with a numpy reference it matches bit for bit: which pixels lie
inside any of a set of ellipses (:func:`covered`), the image covariances of projected
ellipsoids (:func:`image_covariances`) and the background area an ellipse covers
(:func:`background_area`).

The silhouette limb search (:mod:`core.silhouette_search`) scores every grid hypothesis
of a limb by the foreground pixels its projected ellipsoids cover.  A pixel ``u`` is
inside ellipse ``e`` when ``(u − μ_e)ᵀ S_e (u − μ_e) ≤ 1`` (``S_e`` the inverse shape,
:func:`core.silhouette_search.image_ellipses`; an all-zero ``S_e`` marks an ellipsoid
behind the camera, which covers nothing).  The numpy path builds (H, E, G) temporaries
for H hypotheses, E ellipses and G pixels, and was the fit's largest single cost on
make demo's walk (41 s of 300); the compiled path loops and stops at the first ellipse
that covers a pixel.  Both evaluate the quadratic form in the same order, so they agree
bit for bit.  The other two kernels replace numpy temporaries over the few thousand
ellipses of a limb's grid (with the camera's projection, 49 s of the search's 86 in
walk_ortho3's fit before they were compiled) and keep numpy's order of operations.

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
    """:func:`covered_numpy` as loops over hypotheses, pixels and ellipses; fills out.

    A pixel outside an ellipse's bounding box (half-widths ``sqrt`` of the covariance's
    diagonal, ``inv⁻¹``, widened by a relative 1e-6 and 1e-6 px) is not tested against
    it, and one outside every box of the hypothesis against none: the quadratic form
    exceeds 1 there by far more than its rounding, so the answer is the same."""
    H, E = mu.shape[0], mu.shape[1]
    live = np.empty(E, np.bool_)
    lo = np.empty((E, 2))
    hi = np.empty((E, 2))
    for h in range(H):
        box_lo = np.array([np.inf, np.inf])
        box_hi = np.array([-np.inf, -np.inf])
        for e in range(E):
            a, b, c, d = inv[h, e, 0, 0], inv[h, e, 0, 1], inv[h, e, 1, 0], inv[h, e, 1, 1]
            live[e] = a != 0.0 or b != 0.0 or c != 0.0 or d != 0.0
            det = a * d - b * b  # of the symmetric form the test evaluates
            if live[e] and det > 0.0 and a > 0.0 and d > 0.0:
                hu = np.sqrt(d / det) * (1.0 + 1e-6) + 1e-6
                hv = np.sqrt(a / det) * (1.0 + 1e-6) + 1e-6
            else:  # no box: always tested
                hu = hv = np.inf
            lo[e, 0], hi[e, 0] = mu[h, e, 0] - hu, mu[h, e, 0] + hu
            lo[e, 1], hi[e, 1] = mu[h, e, 1] - hv, mu[h, e, 1] + hv
            if live[e]:
                for k in range(2):
                    box_lo[k] = min(box_lo[k], lo[e, k])
                    box_hi[k] = max(box_hi[k], hi[e, k])
        for g in range(uv.shape[0]):
            u, v = uv[g, 0], uv[g, 1]
            if not (box_lo[0] <= u <= box_hi[0] and box_lo[1] <= v <= box_hi[1]):
                continue
            for e in range(E):
                if not live[e]:
                    continue
                if u < lo[e, 0] or u > hi[e, 0] or v < lo[e, 1] or v > hi[e, 1]:
                    continue
                du = u - mu[h, e, 0]
                dv = v - mu[h, e, 1]
                q = (
                    inv[h, e, 0, 0] * du * du
                    + 2.0 * inv[h, e, 0, 1] * du * dv
                    + inv[h, e, 1, 1] * dv * dv
                )
                if q <= 1.0:
                    out[h, g] = True
                    break


def image_covariances(axes: np.ndarray, radii: np.ndarray, J: np.ndarray) -> np.ndarray:
    """Image covariances ``J A diag(r²) Aᵀ Jᵀ`` (M, 2, 2), px², of ellipsoids.

    Parameters
    ----------
    axes : (M, 3, 3) world axes of each ellipsoid as columns (A)
    radii : (M, 3) semi-axes, metres
    J : (M, 2, 3) the projection's Jacobian at each centre, px / m
    """
    axes = np.ascontiguousarray(axes, float).reshape(-1, 3, 3)
    r2 = np.ascontiguousarray(np.asarray(radii, float).reshape(-1, 3) ** 2)
    J = np.ascontiguousarray(J, float).reshape(-1, 2, 3)
    if enabled() and len(axes):
        out = np.empty((len(axes), 2, 2))
        if run(_covariance_loops, axes, r2, J, out):
            return out
    return image_covariances_numpy(axes, r2, J)


def image_covariances_numpy(axes: np.ndarray, r2: np.ndarray, J: np.ndarray) -> np.ndarray:
    """:func:`image_covariances` from the squared radii ``r2``: the reference, the sums
    in the order ``np.einsum("mij,mj,mkj->mik")`` then ``("mai,mij,mbj->mab")`` takes
    them (the bits the search had with those)."""
    ar = axes * r2[:, None, :]
    cov3 = np.empty_like(axes)
    for i in range(3):
        for k in range(3):
            cov3[:, i, k] = (
                ar[:, i, 0] * axes[:, k, 0]
                + ar[:, i, 1] * axes[:, k, 1]
                + ar[:, i, 2] * axes[:, k, 2]
            )
    cov2 = np.empty(J.shape[:1] + (2, 2))
    for a in range(2):
        for b in range(2):
            acc = J[:, a, 0] * cov3[:, 0, 0] * J[:, b, 0]
            for i in range(3):
                for j in range(3):
                    if i or j:
                        acc = acc + J[:, a, i] * cov3[:, i, j] * J[:, b, j]
            cov2[:, a, b] = acc
    return cov2


@jit()
def _covariance_loops(axes, r2, J, out):  # pragma: no cover - compiled
    """:func:`image_covariances_numpy` per ellipsoid; fills out (M, 2, 2)."""
    cov3 = np.empty((3, 3))
    for m in range(axes.shape[0]):
        for i in range(3):
            for k in range(3):
                cov3[i, k] = (
                    axes[m, i, 0] * r2[m, 0] * axes[m, k, 0]
                    + axes[m, i, 1] * r2[m, 1] * axes[m, k, 1]
                    + axes[m, i, 2] * r2[m, 2] * axes[m, k, 2]
                )
        for a in range(2):
            for b in range(2):
                acc = J[m, a, 0] * cov3[0, 0] * J[m, b, 0]
                for i in range(3):
                    for j in range(3):
                        if i or j:
                            acc = acc + J[m, a, i] * cov3[i, j] * J[m, b, j]
                out[m, a, b] = acc


#: Unit-disc sample pattern (K, 2) for the background a projected ellipse covers: the
#: centre and two rings of six, at radii splitting the disc into near-equal areas.
DISC = np.vstack(
    [np.zeros((1, 2))]
    + [
        r * np.stack([np.cos(a), np.sin(a)], axis=1)
        for r, a in ((0.5, np.arange(6) * np.pi / 3), (0.85, (np.arange(6) + 0.5) * np.pi / 3))
    ]
)


def background_area(mask: np.ndarray, mu: np.ndarray, inv: np.ndarray) -> np.ndarray:
    """Background area (..., E) in pixels that ellipses cover: each ellipse's area times
    the share of its :data:`DISC` samples on background (outside the image counts as
    background).

    Parameters
    ----------
    mask : (H, W) bool foreground
    mu : (..., E, 2) ellipse centres, px
    inv : (..., E, 2, 2) inverse shapes, 1/px² (a singular one covers nothing: 0)
    """
    mu, inv = np.asarray(mu, float), np.asarray(inv, float)
    lead = mu.shape[:-1]
    if enabled() and mu.size:
        out = np.empty(int(np.prod(lead, dtype=int)))
        args = (
            np.ascontiguousarray(mask, np.bool_),
            np.ascontiguousarray(mu.reshape(-1, 2)),
            np.ascontiguousarray(inv.reshape(-1, 2, 2)),
            DISC,
            out,
        )
        if run(_background_loops, *args):
            return out.reshape(lead)
    return background_area_numpy(mask, mu, inv)


def background_area_numpy(mask: np.ndarray, mu: np.ndarray, inv: np.ndarray) -> np.ndarray:
    """:func:`background_area` with numpy arrays over (..., E, K): the reference."""
    a, b, c = inv[..., 0, 0], inv[..., 0, 1], inv[..., 1, 1]
    det = a * c - b * b
    live = det > 1e-18
    det = np.where(live, det, 1.0)
    # covariance = inv⁻¹, its Cholesky factor maps the unit disc onto the ellipse
    s00, s01, s11 = c / det, -b / det, a / det
    l00 = np.sqrt(np.maximum(s00, 0.0))
    l10 = s01 / np.maximum(l00, 1e-12)
    l11 = np.sqrt(np.maximum(s11 - l10**2, 0.0))
    u = mu[..., None, 0] + l00[..., None] * DISC[:, 0]
    v = mu[..., None, 1] + l10[..., None] * DISC[:, 0] + l11[..., None] * DISC[:, 1]
    h, w = mask.shape
    iu, iv = np.rint(u).astype(np.int64), np.rint(v).astype(np.int64)
    inside = (iu >= 0) & (iv >= 0) & (iu < w) & (iv < h)
    fg = np.zeros(iu.shape, bool)
    fg[inside] = mask[iv[inside], iu[inside]]
    area = np.pi / np.sqrt(det)
    return np.where(live, area * (1.0 - fg.mean(axis=-1)), 0.0)


@jit()
def _background_loops(mask, mu, inv, disc, out):  # pragma: no cover - compiled
    """:func:`background_area_numpy` per ellipse; fills out (M,)."""
    h, w = mask.shape
    K = disc.shape[0]
    for m in range(mu.shape[0]):
        a, b, c = inv[m, 0, 0], inv[m, 0, 1], inv[m, 1, 1]
        det = a * c - b * b
        if not det > 1e-18:
            out[m] = 0.0
            continue
        s00, s01, s11 = c / det, -b / det, a / det
        l00 = np.sqrt(max(s00, 0.0))
        l10 = s01 / max(l00, 1e-12)
        l11 = np.sqrt(max(s11 - l10 * l10, 0.0))
        n_fg = 0
        for k in range(K):
            iu = np.int64(np.rint(mu[m, 0] + l00 * disc[k, 0]))
            iv = np.int64(np.rint(mu[m, 1] + l10 * disc[k, 0] + l11 * disc[k, 1]))
            if iu >= 0 and iv >= 0 and iu < w and iv < h and mask[iv, iu]:
                n_fg += 1
        out[m] = np.pi / np.sqrt(det) * (1.0 - n_fg / K)
