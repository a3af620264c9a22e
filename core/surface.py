"""Dense surface measurement at one frame by region growing with LSM (D'Apuzzo 1999).

A grid of step ``step`` px is laid over the reference camera.  Starting from a few
seed points (clicked joints from ``clicks.json``, or given ``uv``), each wave takes the
4-neighbours of the points matched so far, predicts their positions in the other
cameras from the matched neighbour (its position plus its LSM affine times the grid
offset), refines them by least squares matching from the reference camera into every
other camera (all candidates of a wave in one batched call), and keeps those matched in
at least one other camera whose forward intersection has a small reprojection RMS and
lies close in space to the neighbour it grew from.  Growth stops at weak texture
(a plain background), occlusions (failed or inconsistent matches) and depth jumps.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .camera import Camera
from .errors import InputError
from .intersect import triangulate
from .lsm import ImageStack, match
from .ncc import search
from .track_smooth import depth_outliers

#: Default Gaussian weighting σ of the LSM patches, pixels (measured on the sample scene).
WEIGHT_SIGMA = 4.0
#: Narrower weighting σ of the final re-match (:func:`refine`), pixels.
REFINE_SIGMA = 1.5

#: Default seed joints, in order of preference (on the torso and thighs: large, textured).
SEED_JOINTS = ("pelvis", "neck", "l_hip", "r_hip", "l_shoulder", "r_shoulder", "l_knee", "r_knee")


@dataclass
class Surface:
    """A measured point cloud with its correspondences.

    Attributes
    ----------
    xyz : ndarray, shape (N, 3)
        World points, metres.
    cov : ndarray, shape (N, 3, 3)
        Covariance of ``xyz``, m² (from the LSM σ of the image points).
    uv : ndarray, shape (N, C, 2)
        Image points, pixels; NaN where a camera did not match.
    affine : ndarray, shape (N, C, 2, 2)
        LSM affine from the reference camera to each camera (identity in the reference).
    sigma_uv : ndarray, shape (N, C)
        LSM standard deviation of the image position (larger of u, v), pixels.
    rms : ndarray, shape (N,)
        Reprojection RMS of the forward intersection, pixels.
    ref : int
        Index of the reference (template) camera.
    """

    xyz: np.ndarray
    cov: np.ndarray
    uv: np.ndarray
    affine: np.ndarray
    sigma_uv: np.ndarray
    rms: np.ndarray
    ref: int

    def __len__(self) -> int:
        return len(self.xyz)


def seeds_from_clicks(
    clicks: dict, cameras: list[str], max_seeds: int = 5, path: str | Path = "clicks.json"
) -> np.ndarray:
    """Seed image points ``(S, C, 2)`` from ``Scene.clicks()`` (NaN where not clicked);
    ``path`` names the clicks file in the error."""
    joints = clicks["joints"]
    names = [j for j in SEED_JOINTS if j in joints] + [j for j in joints if j not in SEED_JOINTS]
    out = []
    for j in names:
        per = joints[j]
        if sum(c in per for c in cameras) < 2:
            continue
        out.append([per.get(c, (np.nan, np.nan)) for c in cameras])
        if len(out) == max_seeds:
            break
    if not out:
        raise InputError(f"{path}: no joint is clicked in two or more cameras")
    return np.asarray(out, float)


def _match_views(
    stack: ImageStack,
    cams: list[Camera],
    ref: int,
    uv_ref: np.ndarray,
    uv_pred: np.ndarray,
    aff_pred: np.ndarray,
    *,
    half: int,
    ncc_radius: int,
    max_rms_px: float,
    sigma_px: float,
    weight_sigma: float | None = None,
    max_sigma_px: float = 0.15,
):
    """Match reference points into all other cameras; returns uv, affine, sigma, xyz, ok."""
    n, c = uv_pred.shape[:2]
    others = [j for j in range(c) if j != ref]
    uv = np.full((n, c, 2), np.nan)
    aff = np.tile(np.eye(2), (n, c, 1, 1))
    sig = np.full((n, c), np.nan)
    uv[:, ref] = uv_ref
    sig[:, ref] = 0.0
    tmpl = np.repeat(uv_ref, len(others), axis=0)
    pred = uv_pred[:, others].reshape(-1, 2)
    sidx = np.tile(others, n)
    start = pred
    if ncc_radius > 0:
        nc = search(
            stack,
            stack,
            tmpl,
            pred,
            half=half,
            radius=ncc_radius,
            template_index=np.full(len(tmpl), ref),
            search_index=sidx,
            min_score=0.6,
        )
        start = np.where(nc.ok[:, None], nc.uv, pred)
    r = match(
        stack,
        stack,
        tmpl,
        start,
        half=half,
        affine=aff_pred[:, others].reshape(-1, 2, 2),
        template_index=np.full(len(tmpl), ref),
        search_index=sidx,
        max_shift_px=max(3.0, ncc_radius + 1.0),
        weight_sigma=weight_sigma,
        max_sigma_px=max_sigma_px,
    )
    ok = r.ok.reshape(n, len(others))
    uv[:, others] = np.where(ok[..., None], r.uv.reshape(n, len(others), 2), np.nan)
    # Failed matches keep the predicted affine part (a diverged one would poison the
    # growth and later re-acquisition in tracking).
    aff[:, others] = np.where(
        ok[..., None, None], r.affine.reshape(n, len(others), 2, 2), aff_pred[:, others]
    )
    sig[:, others] = np.where(ok, r.sigma_uv.max(axis=1).reshape(n, len(others)), np.nan)
    inter = triangulate(cams, uv, sigma_px=sigma_px)
    good = inter.ok & (inter.rms < max_rms_px) & (np.sum(ok, axis=1) >= 1)
    return uv, aff, sig, inter, good


def measure_surface(
    images,
    cameras: list[Camera],
    seeds_uv: np.ndarray,
    *,
    ref: int | None = None,
    step: int = 2,
    half: int = 6,
    max_rms_px: float = 1.0,
    max_jump_m: float = 0.03,
    max_points: int = 50000,
    progress=None,
    occupied_uv: np.ndarray | None = None,
    weight_sigma: float | None = WEIGHT_SIGMA,
    refine_sigma: float | None = REFINE_SIGMA,
    max_sigma_px: float = 0.15,
    max_depth_dev_m: float | None = None,
) -> Surface:
    """Grow a dense point cloud over the textured surface seen by all cameras.

    Parameters
    ----------
    images : sequence of C grey images (H, W), or an :class:`~core.lsm.ImageStack`
        One image per camera, same frame, in camera order.
    cameras : list of Camera, length C
    seeds_uv : ndarray, shape (S, C, 2)
        Approximate corresponding points (NaN where unknown); the reference-camera point
        is the template, the others start an NCC search (radius 12 px).
    ref : int, optional
        Reference camera (default: the middle one).
    step : int
        Grid spacing in the reference image, pixels.
    max_rms_px : float
        Largest reprojection RMS of an accepted point, pixels.
    max_jump_m : float
        Largest 3-D distance between a new point and the neighbour it grew from, metres.
    weight_sigma : float or None
        Gaussian weighting of the LSM patches, pixels (see :func:`core.lsm.match`):
        on a body seen from metres away a 13 × 13 patch spans ~8 cm of curved skin,
        and the affine model over all of it biases the match (the measured point
        lies behind the convex surface).
    refine_sigma : float or None
        After growing, re-match all points with this narrower weighting (:func:`refine`).
    max_sigma_px : float
        Largest LSM σ of an accepted match, pixels (:func:`core.lsm.match`); real video
        with weak skin texture may need a looser one than synthetic renders.
    max_depth_dev_m : float, optional
        Finally drop points whose depth differs from the median of their 8 nearest
        neighbours' by more than this, metres (:func:`core.track_smooth.depth_outliers`,
        seen from the mean camera centre); None (default): keep all.
    occupied_uv : ndarray, shape (K, 2), optional
        Reference-image points already measured (e.g. live tracks): their grid cells are
        not grown again, but growth passes through them.

    Returns
    -------
    Surface
    """
    stack = ImageStack(images)
    c = len(cameras)
    if stack.shape[0] != c:
        raise ValueError(f"{stack.shape[0]} images for {c} cameras")
    ref = c // 2 if ref is None else int(ref)
    _, h, w = stack.shape
    gh, gw = (h - 1) // step + 1, (w - 1) // step + 1
    visited = np.zeros((gh, gw), bool)
    keep = np.ones((gh, gw), bool)
    if occupied_uv is not None and len(occupied_uv):
        o = np.asarray(occupied_uv, float)
        o = np.rint(o[np.all(np.isfinite(o), axis=1)] / step).astype(int)
        o = o[(o[:, 0] >= 0) & (o[:, 0] < gw) & (o[:, 1] >= 0) & (o[:, 1] < gh)]
        keep[o[:, 1], o[:, 0]] = False

    seeds_uv = np.asarray(seeds_uv, float).reshape(-1, c, 2)
    seeds_uv = seeds_uv[np.all(np.isfinite(seeds_uv[:, ref]), axis=1)]
    if len(seeds_uv) == 0:
        raise InputError("surface seeds: no seed point is given in the reference camera")
    # Snap seeds to the grid; the prediction in the other views moves with them.
    g = np.rint(seeds_uv[:, ref] / step).astype(int)
    uv_ref = g * float(step)
    pred = seeds_uv + (uv_ref - seeds_uv[:, ref])[:, None]
    pred = np.where(np.isfinite(pred), pred, uv_ref[:, None])
    aff0 = np.tile(np.eye(2), (len(g), c, 1, 1))
    uv, aff, sig, inter, good = _match_views(
        stack,
        cameras,
        ref,
        uv_ref,
        pred,
        aff0,
        half=half,
        ncc_radius=12,
        max_rms_px=max_rms_px,
        sigma_px=0.05,
        weight_sigma=weight_sigma,
        max_sigma_px=max_sigma_px,
    )
    inb = (g[:, 0] >= 0) & (g[:, 0] < gw) & (g[:, 1] >= 0) & (g[:, 1] < gh)
    good &= inb
    visited[g[inb, 1], g[inb, 0]] = True
    acc = {
        "g": [g[good]],
        "uv": [uv[good]],
        "aff": [aff[good]],
        "sig": [sig[good]],
        "xyz": [inter.xyz[good]],
        "cov": [inter.cov[good]],
        "rms": [inter.rms[good]],
        "keep": [keep[g[good, 1], g[good, 0]]],
    }
    front = (g[good], uv[good], aff[good], inter.xyz[good])
    total = int(good.sum())
    steps = np.array([[1, 0], [-1, 0], [0, 1], [0, -1]])
    wave = 0
    while len(front[0]) and total < max_points:
        fg, fuv, faff, fxyz = front
        cand = (fg[:, None, :] + steps[None]).reshape(-1, 2)
        parent = np.repeat(np.arange(len(fg)), 4)
        inside = (cand[:, 0] >= 0) & (cand[:, 0] < gw) & (cand[:, 1] >= 0) & (cand[:, 1] < gh)
        cand, parent = cand[inside], parent[inside]
        fresh = ~visited[cand[:, 1], cand[:, 0]]
        cand, parent = cand[fresh], parent[fresh]
        # One candidate per cell (the first parent).
        key = cand[:, 1] * gw + cand[:, 0]
        _, first = np.unique(key, return_index=True)
        cand, parent = cand[first], parent[first]
        if len(cand) == 0:
            break
        visited[cand[:, 1], cand[:, 0]] = True
        d = (cand - fg[parent]) * float(step)  # grid offset, pixels
        pu = fuv[parent] + np.einsum("ncij,nj->nci", faff[parent], d)
        uv_ref = cand * float(step)
        pu[:, ref] = uv_ref
        have = np.all(np.isfinite(pu), axis=2)
        pu = np.where(have[..., None], pu, uv_ref[:, None])
        uv, aff, sig, inter, good = _match_views(
            stack,
            cameras,
            ref,
            uv_ref,
            pu,
            faff[parent],
            half=half,
            ncc_radius=0,
            max_rms_px=max_rms_px,
            sigma_px=0.05,
            weight_sigma=weight_sigma,
            max_sigma_px=max_sigma_px,
        )
        jump = np.linalg.norm(inter.xyz - fxyz[parent], axis=1)
        good &= jump < max_jump_m
        for k, v in (
            ("g", cand),
            ("uv", uv),
            ("aff", aff),
            ("sig", sig),
            ("xyz", inter.xyz),
            ("cov", inter.cov),
            ("rms", inter.rms),
            ("keep", keep[cand[:, 1], cand[:, 0]]),
        ):
            acc[k].append(v[good])
        total += int(good.sum())
        front = (cand[good], uv[good], aff[good], inter.xyz[good])
        wave += 1
        if progress is not None:
            progress.update(
                min(total, max_points), max_points, f"surface: wave {wave}, {total} points"
            )
    cat = {k: np.concatenate(v) for k, v in acc.items()}
    k = cat["keep"]
    surf = Surface(
        xyz=cat["xyz"][k],
        cov=cat["cov"][k],
        uv=cat["uv"][k],
        affine=cat["aff"][k],
        sigma_uv=cat["sig"][k],
        rms=cat["rms"][k],
        ref=ref,
    )
    if refine_sigma is not None and len(surf):
        surf = refine(
            stack,
            cameras,
            surf,
            half=half,
            weight_sigma=refine_sigma,
            max_rms_px=max_rms_px,
            max_sigma_px=max_sigma_px,
        )
    if max_depth_dev_m is not None and len(surf):
        out = depth_outliers(
            surf.xyz, np.mean([cam.center for cam in cameras], axis=0), max_depth_dev_m
        )
        surf = subset(surf, ~out)
    return surf


def subset(surf: Surface, keep: np.ndarray) -> Surface:
    """The points ``keep`` (bool (N,) or indices) of a surface."""
    return Surface(
        xyz=surf.xyz[keep],
        cov=surf.cov[keep],
        uv=surf.uv[keep],
        affine=surf.affine[keep],
        sigma_uv=surf.sigma_uv[keep],
        rms=surf.rms[keep],
        ref=surf.ref,
    )


def concat(a: Surface, b: Surface) -> Surface:
    """The points of two surfaces measured with the same cameras and reference."""
    if a.ref != b.ref:
        raise ValueError(f"reference cameras differ: {a.ref} and {b.ref}")
    return Surface(
        *(
            np.concatenate([getattr(a, k), getattr(b, k)])
            for k in ("xyz", "cov", "uv", "affine", "sigma_uv", "rms")
        ),
        ref=a.ref,
    )


def refine(
    images,
    cameras: list[Camera],
    surf: Surface,
    *,
    half: int = 6,
    weight_sigma: float = REFINE_SIGMA,
    max_rms_px: float = 1.0,
    max_sigma_px: float = 0.15,
) -> Surface:
    """Re-match every point of a surface with narrower patch weights, then re-intersect.

    Growing needs the robustness of wide patches; the final coordinates are less biased
    by surface curvature with a narrow Gaussian weighting (``weight_sigma`` px).  One
    batched LSM call from the reference camera into all others, started at the grown
    matches and their affine parts; where the refinement fails, the grown match is
    kept.  Points whose re-intersection reprojects badly keep their grown result.
    """
    stack = ImageStack(images)
    n, c = surf.uv.shape[:2]
    ref = surf.ref
    pi, ci = np.nonzero(np.isfinite(surf.uv[..., 0]) & (np.arange(c) != ref)[None])
    r = match(
        stack,
        stack,
        surf.uv[pi, ref],
        surf.uv[pi, ci],
        half=half,
        affine=surf.affine[pi, ci],
        template_index=np.full(len(pi), ref),
        search_index=ci,
        max_shift_px=1.0,
        weight_sigma=weight_sigma,
        max_sigma_px=max_sigma_px,
    )
    uv = surf.uv.copy()
    uv[pi[r.ok], ci[r.ok]] = r.uv[r.ok]
    aff = surf.affine.copy()
    aff[pi[r.ok], ci[r.ok]] = r.affine[r.ok]
    sig = surf.sigma_uv.copy()
    sig[pi[r.ok], ci[r.ok]] = r.sigma_uv[r.ok].max(axis=1)
    inter = triangulate(cameras, uv, sigma_px=0.05)
    good = inter.ok & (inter.rms < max_rms_px)
    g3 = good[:, None, None]
    return Surface(
        xyz=np.where(good[:, None], inter.xyz, surf.xyz),
        cov=np.where(g3, inter.cov, surf.cov),
        uv=np.where(g3, uv, surf.uv),
        affine=np.where(good[:, None, None, None], aff, surf.affine),
        sigma_uv=np.where(good[:, None], sig, surf.sigma_uv),
        rms=np.where(good, inter.rms, surf.rms),
        ref=ref,
    )
