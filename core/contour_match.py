"""Pair image occluding-contour points with model rim points (the occluding-contour theorem).

If a surface point projects onto the occluding contour, its surface normal is
perpendicular to the viewing plane through the camera centre, the contour point and
the contour tangent (the second paper, sec. 4.1): with ``k`` the unit normal of that
plane, ``|n . k| = 1``.  Each image contour point is paired with the model rim point
of the part whose normal satisfies ``|n . k| >= eps`` and whose projection is nearest
in the image; the residuals are the image offset ``f_im = z - proj(x)`` (pixels) and
the normal offset ``f_3d = n - k`` (sign-aligned).  The offset along the image normal
(the only component a contour can observe) is given separately.

Frames: world Z up, metres; image pixels as in :mod:`core.camera`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .camera import Camera
from .contours import Contour
from .model_contours import RimPoints


@dataclass
class ContourMatches:
    """Correspondences between image contour points and model rim points.

    Attributes
    ----------
    contour_uv : ndarray, shape (M, 2)
        Image contour points, pixels.
    contour_normal : ndarray, shape (M, 2)
        Their outward image normals.
    rim_index : ndarray, shape (M,), int
        Index into the :class:`RimPoints` that were matched.
    f_im : ndarray, shape (M, 2)
        ``z - proj(x)``, pixels.
    normal_residual : ndarray, shape (M,)
        Signed offset along the image normal, ``f_im . n_img``, pixels.
    f_3d : ndarray, shape (M, 3)
        ``n - k`` (with ``k`` oriented like ``n``), dimensionless.
    """

    contour_uv: np.ndarray
    contour_normal: np.ndarray
    rim_index: np.ndarray
    f_im: np.ndarray
    normal_residual: np.ndarray
    f_3d: np.ndarray

    def __len__(self) -> int:
        return len(self.rim_index)


def viewing_plane_normals(camera: Camera, uv: np.ndarray, tangent: np.ndarray) -> np.ndarray:
    """Unit normals ``k`` (M, 3), world, of the planes through the camera centre, the
    image points ``uv`` (M, 2) and their image tangents (M, 2)."""
    _, d0 = camera.rays(uv)
    _, d1 = camera.rays(uv + tangent)
    k = np.cross(d0, d1)
    return k / np.linalg.norm(k, axis=1, keepdims=True)


def match_contours(
    camera: Camera,
    contours: list[Contour],
    rim: RimPoints,
    max_dist_px: float = 15.0,
    eps: float = 0.9,
    parts: np.ndarray | None = None,
) -> ContourMatches:
    """Pair image contour points with visible model rim points.

    Parameters
    ----------
    camera : Camera
    contours : list of Contour
        Observed occluding contours (from the foreground mask).
    rim : RimPoints
        The model's visible rim from the predicted pose.
    max_dist_px : float
        Pairs further apart in the image are not made (gross segmentation errors).
    eps : float
        Minimum ``|n . k|`` (the normal must be nearly perpendicular to the viewing plane).
    parts : ndarray of int, optional
        Restrict the rim to these parts (the parts that selected this camera).

    Returns
    -------
    ContourMatches
    """
    empty = ContourMatches(
        np.zeros((0, 2)),
        np.zeros((0, 2)),
        np.zeros(0, int),
        np.zeros((0, 2)),
        np.zeros(0),
        np.zeros((0, 3)),
    )
    if not contours or len(rim) == 0:
        return empty
    if parts is not None:
        sel = np.flatnonzero(np.isin(rim.part, parts))
    else:
        sel = np.arange(len(rim))
    if len(sel) == 0:
        return empty
    uv = np.vstack([c.uv for c in contours])
    tan = np.vstack([c.tangent for c in contours])
    nim = np.vstack([c.normal for c in contours])
    k = viewing_plane_normals(camera, uv, tan)
    tree = cKDTree(rim.uv[sel])
    n_cand = min(16, len(sel))
    dist, idx = tree.query(uv, k=n_cand, distance_upper_bound=max_dist_px)
    dist = np.atleast_2d(dist.reshape(len(uv), n_cand))
    idx = np.atleast_2d(idx.reshape(len(uv), n_cand))
    valid = np.isfinite(dist)
    idx_safe = np.where(valid, idx, 0)
    cand = sel[idx_safe]  # (M, n_cand)
    cos = np.abs(np.einsum("mj,mcj->mc", k, rim.normal[cand]))
    good = valid & (cos >= eps)
    # nearest good candidate (candidates are sorted by distance)
    first = np.argmax(good, axis=1)
    has = good[np.arange(len(uv)), first]
    m = np.flatnonzero(has)
    ri = cand[m, first[m]]
    f_im = uv[m] - rim.uv[ri]
    n3 = rim.normal[ri]
    km = k[m] * np.sign(np.einsum("mj,mj->m", k[m], n3))[:, None]
    return ContourMatches(uv[m], nim[m], ri, f_im, np.einsum("mj,mj->m", f_im, nim[m]), n3 - km)
