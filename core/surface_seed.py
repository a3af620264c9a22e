"""Seeds for surface the region growing cannot reach: a search along the epipolar lines.

Region growing (:func:`core.surface.measure_surface`) predicts each new point from the
neighbour it grew from, so it stops at a depth jump: a limb seen beside or behind the
trunk, or one that swings out from behind it, is never reached from the trunk's points
(on the sample walk through line3 not one point landed on the right arm in 50 frames).
Here every textured cell of a coarse grid over the reference image that no measured
point covers is tried at a range of depths along its viewing ray: the reference
template is compared by normalised cross-correlation with the patch at the depth's
projection in every other camera, and the depth where *every* camera agrees best —
distinctly better than elsewhere on the ray — gives a seed.  The seeds then grow by
LSM like any other (:func:`grow_from_jumps`), which checks them again (multi-view LSM,
reprojection RMS).

Shapes: C cameras, N candidate cells, K depths; world metres, pixels.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.spatial import cKDTree

from .camera import Camera
from .lsm import ImageStack


def _box_std(img: np.ndarray, half: int) -> np.ndarray:
    """Standard deviation (H, W) of the grey levels in the (2 half + 1)² box."""
    k = (2 * half + 1, 2 * half + 1)
    m = cv2.blur(img, k, borderType=cv2.BORDER_REPLICATE)
    m2 = cv2.blur(img * img, k, borderType=cv2.BORDER_REPLICATE)
    return np.sqrt(np.maximum(m2 - m * m, 0.0))


def _patches(img: np.ndarray, uv: np.ndarray, half: int) -> np.ndarray:
    """Zero-mean, unit-norm patches (..., (2 half + 1)²) at the rounded points ``uv``
    (..., 2) of ``img`` (H, W); the points must lie ``half`` px inside the image."""
    off = np.arange(-half, half + 1)
    iu = np.rint(uv[..., 0]).astype(int)[..., None, None] + off[None, :]
    iv = np.rint(uv[..., 1]).astype(int)[..., None, None] + off[:, None]
    p = img[iv, iu].reshape(*uv.shape[:-1], -1)
    p = p - p.mean(axis=-1, keepdims=True)
    return p / np.maximum(np.linalg.norm(p, axis=-1, keepdims=True), 1e-9)


def epipolar_seeds(
    images,
    cameras: list[Camera],
    ref: int,
    depth_range: tuple[float, float],
    occupied_uv: np.ndarray | None = None,
    *,
    step: int = 8,
    half: int = 6,
    min_std: float = 4.0,
    min_ncc: float = 0.7,
    min_margin: float = 0.1,
    max_seeds: int = 300,
    chunk: int = 64,
) -> np.ndarray:
    """Correspondences found by a depth search along the reference camera's rays.

    Parameters
    ----------
    images : C grey images (H, W) or an :class:`~core.lsm.ImageStack`, one per camera
    cameras : list (C) of Camera
    ref : int
        Reference camera: its grid cells are the candidates and its patches the
        templates.
    depth_range : (near, far)
        Distances along the reference camera's viewing rays to search, metres (e.g. the
        measured cloud's range with a margin).
    occupied_uv : (M, 2), optional
        Reference-image points already measured: cells within ``step`` px of one are not
        tried.
    step : int
        Grid spacing of the candidate cells, pixels.
    half : int
        Template half width (13 × 13 for 6).
    min_std : float
        Least grey-level standard deviation of a candidate's reference patch (texture).
    min_ncc : float
        Least correlation, in the camera that agrees least, at the chosen depth (the
        seeds' LSM growth checks them again; at frame 1 of walk_line3 0.7 gave 22 seeds
        and 279 points grown on the right arm, 0.85 gave 4 seeds and none there).
    min_margin : float
        The chosen depth's score must exceed the best score more than two depth steps
        away by this much (a repeated texture along the ray gives no seed).
    max_seeds : int
        At most this many seeds (the best scores first).
    chunk : int
        Candidates per batch (memory).

    Returns
    -------
    ndarray, shape (S, C, 2)
        Seed points in every camera, pixels (S may be 0).
    """
    stack = ImageStack(images)
    imgs = np.asarray(stack.images, float)
    c, h, w = imgs.shape
    others = [j for j in range(c) if j != ref]
    empty = np.zeros((0, c, 2))
    if not others:
        return empty
    m = half + 1
    gu, gv = np.meshgrid(np.arange(m, w - m, step), np.arange(m, h - m, step))
    cand = np.stack([gu.ravel(), gv.ravel()], axis=1).astype(float)
    cand = cand[
        _box_std(imgs[ref], half)[cand[:, 1].astype(int), cand[:, 0].astype(int)] >= min_std
    ]
    if occupied_uv is not None and len(occupied_uv) and len(cand):
        occ = np.asarray(occupied_uv, float).reshape(-1, 2)
        occ = occ[np.all(np.isfinite(occ), axis=1)]
        if len(occ):
            d, _ = cKDTree(occ).query(cand)
            cand = cand[d > step]
    if len(cand) == 0:
        return empty
    near, far = float(depth_range[0]), float(depth_range[1])
    o, ray = cameras[ref].rays(cand)
    # depth steps of at most about one pixel of image motion in every other camera
    ends = np.stack([o + near * ray, o + far * ray], axis=1)  # (N, 2, 3)
    span = max(
        float(
            np.nanmax(
                np.linalg.norm(
                    np.diff(cameras[j].project(ends.reshape(-1, 3)).reshape(-1, 2, 2), axis=1),
                    axis=-1,
                )
            )
        )
        for j in others
    )
    k = int(np.clip(np.ceil(span), 2, 600)) + 1
    depths = np.linspace(near, far, k)
    tmpl = _patches(imgs[ref], cand, half)  # (N, P)
    best = np.full(len(cand), -np.inf)
    best_k = np.zeros(len(cand), int)
    second = np.full(len(cand), -np.inf)
    for a in range(0, len(cand), chunk):
        sl = slice(a, a + chunk)
        X = o + depths[None, :, None] * ray[sl, None, :]  # (n, K, 3)
        score = np.full(X.shape[:2], np.inf)
        for j in others:
            uv = cameras[j].project(X.reshape(-1, 3)).reshape(*X.shape[:2], 2)
            inside = (
                np.all(np.isfinite(uv), axis=-1)
                & (uv[..., 0] >= m)
                & (uv[..., 0] < w - m)
                & (uv[..., 1] >= m)
                & (uv[..., 1] < h - m)
            )
            uv = np.where(inside[..., None], uv, m)
            ncc = np.einsum("nkp,np->nk", _patches(imgs[j], uv, half), tmpl[sl])
            score = np.minimum(score, np.where(inside, ncc, -1.0))
        kb = np.argmax(score, axis=1)
        far_off = np.abs(np.arange(k)[None] - kb[:, None]) > 2
        best[sl] = score[np.arange(len(kb)), kb]
        best_k[sl] = kb
        second[sl] = np.where(far_off, score, -np.inf).max(axis=1)
    ok = (best >= min_ncc) & (best - second >= min_margin)
    idx = np.flatnonzero(ok)
    idx = idx[np.argsort(-best[idx])][:max_seeds]
    X = o + depths[best_k[idx], None] * ray[idx]
    seeds = np.stack([cam.project(X) for cam in cameras], axis=1)
    seeds[:, ref] = cand[idx]
    return seeds


def cloud_depth_range(
    cameras: list[Camera], ref: int, xyz: np.ndarray, margin_m: float = 0.5
) -> tuple[float, float] | None:
    """Distances (near, far) from the reference camera's centre spanned by the points
    ``xyz`` (N, 3), widened by ``margin_m`` metres; None without finite points."""
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    xyz = xyz[np.all(np.isfinite(xyz), axis=1)]
    if not len(xyz):
        return None
    d = np.linalg.norm(xyz - cameras[ref].center, axis=1)
    return max(float(d.min()) - margin_m, 0.05), float(d.max()) + margin_m


def grow_from_jumps(
    images,
    cameras: list[Camera],
    ref: int,
    xyz: np.ndarray,
    occupied_uv: np.ndarray,
    *,
    step: int = 2,
    half: int = 6,
    max_sigma_px: float = 0.15,
    max_depth_dev_m: float | None = 0.01,
    margin_m: float = 0.5,
    min_ncc: float = 0.7,
    min_std: float = 4.0,
):
    """Surface beyond the depth jumps that region growing stops at.

    :func:`epipolar_seeds` over the cells that ``occupied_uv`` (M, 2) (reference image)
    leaves free, within ``margin_m`` of the depth range of the measured points ``xyz``
    (N, 3), grown like the frame-0 surface (:func:`core.surface.measure_surface`, the
    other arguments as there).  Returns a :class:`core.surface.Surface` (possibly
    empty), or None when there is nothing to seed from.
    """
    from .surface import measure_surface

    rng = cloud_depth_range(cameras, ref, xyz, margin_m)
    if rng is None:
        return None
    seeds = epipolar_seeds(
        images, cameras, ref, rng, occupied_uv, half=half, min_ncc=min_ncc, min_std=min_std
    )
    if not len(seeds):
        return None
    return measure_surface(
        images,
        cameras,
        seeds,
        ref=ref,
        step=step,
        half=half,
        occupied_uv=occupied_uv,
        max_sigma_px=max_sigma_px,
        max_depth_dev_m=max_depth_dev_m,
    )
