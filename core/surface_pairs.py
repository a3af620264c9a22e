"""Surface the reference camera does not see, measured by pairs of the other cameras.

The surface is grown on the reference camera's grid (:func:`core.surface.measure_surface`)
and the seeds beyond depth jumps are searched along its rays
(:func:`core.surface_seed.grow_from_jumps`), so a point needs the reference camera.
Through ``line3`` the reference is the middle camera; a limb behind the near one — the
far leg of a side-on jump — is hidden there yet seen by the two outer cameras, 38°
apart (on jumps_line3 the right shin shows 31–71 % of its area to each of them in every
frame, 2–14 % to the middle one).  Here every pair of the other cameras measures the
surface it sees and no measured point covers: the first camera of the pair takes the
reference's role in :func:`~core.surface_seed.grow_from_jumps`, and the points are
returned in all C cameras (NaN where not measured) with their affine parts re-based on
the reference camera where it matched, else the identity.

Shapes: C cameras, N points; world metres, pixels.
"""

from __future__ import annotations

from itertools import combinations

import numpy as np

from .camera import Camera
from .image_stack import ImageStack
from .surface import Surface, concat


def widen(surf: Surface, views: list[int], n_cameras: int, ref: int) -> Surface:
    """A surface measured in the cameras ``views`` (its ``ref`` indexing ``views``) as
    one of ``n_cameras`` cameras referenced to camera ``ref``.

    The affine parts (reference → camera) are re-based on ``ref`` where it is one of
    ``views``; elsewhere, as for an unmatched camera, they are the identity.
    """
    n = len(surf)
    uv = np.full((n, n_cameras, 2), np.nan)
    sig = np.full((n, n_cameras), np.nan)
    aff = np.tile(np.eye(2), (n, n_cameras, 1, 1))
    uv[:, views] = surf.uv
    sig[:, views] = surf.sigma_uv
    if ref in views:
        inv = np.linalg.inv(surf.affine[:, views.index(ref)])
        aff[:, views] = np.einsum("ncij,njk->ncik", surf.affine, inv)
    return Surface(
        xyz=surf.xyz, cov=surf.cov, uv=uv, affine=aff, sigma_uv=sig, rms=surf.rms, ref=ref
    )


def empty_surface(n_cameras: int, ref: int) -> Surface:
    """A surface of no points in ``n_cameras`` cameras."""
    return Surface(
        xyz=np.zeros((0, 3)),
        cov=np.zeros((0, 3, 3)),
        uv=np.zeros((0, n_cameras, 2)),
        affine=np.zeros((0, n_cameras, 2, 2)),
        sigma_uv=np.zeros((0, n_cameras)),
        rms=np.zeros(0),
        ref=ref,
    )


def grow_pairs(
    images,
    cameras: list[Camera],
    ref: int,
    xyz: np.ndarray,
    occupied: list[np.ndarray],
    *,
    step: int = 2,
    half: int = 6,
    max_sigma_px: float = 0.15,
    max_depth_dev_m: float | None = 0.01,
) -> Surface:
    """Surface measured by every pair of cameras other than ``ref``.

    Parameters
    ----------
    images : C grey images (H, W) or an :class:`~core.image_stack.ImageStack`
    cameras : list (C) of Camera
    ref : int, the reference camera of the surface the points join
    xyz : (N, 3) measured points, metres: their depth range bounds the search
    occupied : list (C) of (M_c, 2) image points already measured in each camera
        (pixels); their cells are not seeded again
    step, half, max_sigma_px, max_depth_dev_m : as
        :func:`core.surface_seed.grow_from_jumps`

    Returns
    -------
    Surface in all C cameras referenced to ``ref`` (possibly empty).
    """
    from .surface_seed import grow_from_jumps

    imgs = ImageStack(images).images
    c = len(cameras)
    out = empty_surface(c, ref)
    for a, b in combinations([j for j in range(c) if j != ref], 2):
        occ = [np.asarray(occupied[a], float).reshape(-1, 2)]
        if len(out):  # what an earlier pair measured
            occ.append(out.uv[:, a])
        got = grow_from_jumps(
            imgs[[a, b]],
            [cameras[a], cameras[b]],
            0,
            xyz,
            np.concatenate(occ),
            step=step,
            half=half,
            max_sigma_px=max_sigma_px,
            max_depth_dev_m=max_depth_dev_m,
        )
        if got is not None and len(got):
            out = concat(out, widen(got, [a, b], c, ref))
    return out
