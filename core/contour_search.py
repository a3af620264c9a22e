"""A small search for limbs the contour tracker has lost (fast motion, paper 2).

The contour EKF pairs each observed contour point with the nearest model rim point, so
its capture range is a few pixels to ``max_dist_px``: a forearm or a shin that moved
20–30 cm between two frames (a dance at 25 fps) is left behind, inside the silhouette
of another part, where no contour calls it back.  Before the update, every limb (upper
arm, forearm and hand; thigh, shin and foot) is re-posed by a random search over its
root and middle joints around the prediction (``rounds`` rounds, each narrower about the
best candidate so far), scored against the silhouettes of every
camera with the rest of the body held fixed:

* **containment** — points inside the limb's metaballs must project into the
  foreground: the mean distance outside it (pixels, :class:`core.contour_obs.SilhouetteField`);
* **explanation** — the observed contour points the rest of the body does not
  explain (further than ``explained_px`` from its rendered silhouette) should lie on
  the limb: their mean distance to the limb's projected surface points, capped at
  ``cap_px``.

A candidate replaces the prediction only when it lowers the score by ``min_gain_px``;
the caller then widens that limb's prior so that the contours refine it.

Frames: world Z up, metres; angles in radians; image pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

from .camera import Camera
from .contour_obs import SilhouetteField
from .contours import Contour
from .metaballs import Metaballs, world_frames
from .model_render import render_parts
from .skeleton import Skeleton, forward

#: Limb -> (its bones, the DOFs searched).  ``trunk`` (searched first) is the whole
#: body turned about the pelvis and moved (the root position is searched too).
LIMBS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "trunk": ((), ("pelvis_z", "pelvis_x", "pelvis_y")),
    **{
        f"{s}_{limb}": (tuple(f"{s}_{b}" for b in bones), tuple(f"{s}_{d}" for d in dofs))
        for s in ("l", "r")
        for limb, bones, dofs in (
            (
                "arm",
                ("shoulder", "elbow", "wrist"),
                ("shoulder_x", "shoulder_y", "shoulder_z", "elbow_x"),
            ),
            ("leg", ("hip", "knee", "ankle"), ("hip_x", "hip_y", "hip_z", "knee_x")),
        )
    },
}


def _sphere_points() -> np.ndarray:
    """Unit-sphere directions (26) plus inner points (7), shape (33, 3)."""
    g = np.array(
        [
            [x, y, z]
            for x in (-1, 0, 1)
            for y in (-1, 0, 1)
            for z in (-1, 0, 1)
            if (x, y, z) != (0, 0, 0)
        ],
        float,
    )
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    inner = np.vstack([np.zeros(3), 0.5 * np.eye(3), -0.5 * np.eye(3)])
    return np.vstack([g, inner])


_POINTS = _sphere_points()
_N_SURFACE = 26


@dataclass
class SearchSettings:
    """Parameters of the limb search (units in brackets)."""

    samples: int = 32  # random candidates per limb and round
    rounds: int = 2  # search rounds, each narrower about the best so far
    shrink: float = 0.35  # spread of a round relative to the previous one
    sigma_theta: float = 0.45  # spread of the candidates about the prediction [rad]
    sigma_trunk: float = 0.2  # ... of the trunk's angles [rad]
    sigma_root: float = 0.05  # ... of the root position [m]
    explained_px: float = 4.0  # contour points nearer the rest of the body are explained
    cap_px: float = 40.0  # distances capped here [px]
    tol_px: float = 2.0  # distance outside the foreground that is free [px]
    min_gain_px: float = 1.0  # a candidate must lower the score by this much [px]
    seed: int = 0


@dataclass
class SearchResult:
    """Outcome of one frame's search.

    Attributes
    ----------
    theta : ndarray, shape (n,)
        Angles with the moved limbs re-posed, radians.
    root : ndarray, shape (3,)
        Root position (moved with the trunk), metres.
    moved : list of str
        Limbs (keys of :data:`LIMBS`) whose pose was replaced.
    gain_px : dict
        Score decrease per limb searched (pixels; 0 when the prediction was best).
    """

    theta: np.ndarray
    root: np.ndarray
    moved: list
    gain_px: dict


def _limb_scores(skel, thetas, roots, s, balls, sel, cameras, fields, unexplained, cfg):
    """Score (K,) of K candidate poses (angles (K, n), roots (K, 3)) of the metaballs ``sel``."""
    K = len(thetas)
    pose = forward(skel, thetas, roots, s)
    Rw, cw = world_frames(skel, pose, balls, s)  # (K, M, 3, 3), (K, M, 3)
    Rw, cw = Rw[:, sel], cw[:, sel]
    r = balls.visible[sel]  # (E, 3)
    pts = cw[:, :, None] + np.einsum("keij,epj->kepi", Rw, _POINTS[None] * r[:, None])
    E, S = len(sel), len(_POINTS)
    score = np.zeros(K)
    for cam, fld, z in zip(cameras, fields, unexplained, strict=True):
        uv = cam.project(pts.reshape(-1, 3)).reshape(K, E, S, 2)
        d, _ = fld.sample(uv[:, :, _N_SURFACE:].reshape(-1, 2))
        d = np.minimum(np.nan_to_num(d, nan=cfg.cap_px) - cfg.tol_px, cfg.cap_px)
        score += np.maximum(d, 0.0).reshape(K, -1).mean(axis=1)
        if len(z):
            for k in range(K):
                dist, _ = cKDTree(uv[k].reshape(-1, 2)).query(z, distance_upper_bound=cfg.cap_px)
                score[k] += np.minimum(dist, cfg.cap_px).mean()
    return score


def search_limbs(
    skel: Skeleton,
    theta: np.ndarray,
    root: np.ndarray,
    s: np.ndarray,
    balls: Metaballs,
    cameras: list[Camera],
    contours: list[list[Contour]],
    fields: list[SilhouetteField],
    rays: list | None = None,
    cfg: SearchSettings | None = None,
) -> SearchResult:
    """Re-pose the limbs that explain the silhouettes better elsewhere.

    Parameters
    ----------
    skel, s, balls
        The body.
    theta : ndarray, shape (n,); root : ndarray, shape (3,)
        Predicted pose (radians, metres).
    cameras : list of Camera (C)
    contours : list (C) of list of Contour
        Observed occluding contours of this frame.
    fields : list (C) of SilhouetteField
        Distance outside each camera's foreground.
    rays : list (C) of ndarray (H, W, 3), optional
        Cached viewing rays (:func:`core.model_render.camera_rays`).

    Returns
    -------
    SearchResult
    """
    cfg = cfg or SearchSettings()
    rng = np.random.default_rng(cfg.seed)
    theta = np.asarray(theta, float).copy()
    root = np.asarray(root, float).copy()
    n_parts = len(skel.bone_names)
    contour_uv = [
        np.vstack([c.uv for c in cons]) if cons else np.zeros((0, 2)) for cons in contours
    ]
    moved, gains = [], {}
    for name, (bones, dofs) in LIMBS.items():
        trunk = not bones
        b_idx = list(range(n_parts)) if trunk else [skel.bone_names.index(b) for b in bones]
        d_idx = np.array([skel.dof_index(d) for d in dofs])
        sel = np.flatnonzero(np.isin(balls.bone, b_idx))
        rest = np.flatnonzero(~np.isin(balls.bone, b_idx))
        if len(sel) == 0:
            continue
        pose = forward(skel, theta[None], root[None], s)
        Rw, cw = world_frames(skel, pose, balls, s)
        unexplained = []
        for c, cam in enumerate(cameras):
            if len(contour_uv[c]) == 0 or len(rest) == 0:
                unexplained.append(contour_uv[c])
                continue
            rnd = render_parts(
                cam,
                cw[0, rest],
                Rw[0, rest],
                balls.visible[rest],
                balls.bone[rest],
                n_parts,
                rays=None if rays is None else rays[c],
            )
            dt = cv2.distanceTransform((~rnd.mask).astype(np.uint8), cv2.DIST_L2, 5)
            h, w = dt.shape
            uv = contour_uv[c]
            iu = np.clip(np.round(uv[:, 0]).astype(int), 0, w - 1)
            iv = np.clip(np.round(uv[:, 1]).astype(int), 0, h - 1)
            unexplained.append(uv[dt[iv, iu] > cfg.explained_px])
        sig = cfg.sigma_trunk if trunk else cfg.sigma_theta
        best_th, best_rt, best_score, start_score = theta, root, np.inf, None
        for rnd in range(max(1, cfg.rounds)):
            # round 0 about the prediction, later rounds narrower about the best so far
            scale = cfg.shrink**rnd
            cand = np.repeat(best_th[None], cfg.samples + 1, axis=0)
            roots = np.repeat(best_rt[None], cfg.samples + 1, axis=0)
            cand[1:, d_idx] += rng.normal(0.0, sig * scale, (cfg.samples, len(d_idx)))
            cand[:, d_idx] = np.clip(cand[:, d_idx], skel.dof_lo[d_idx], skel.dof_hi[d_idx])
            if trunk:
                roots[1:] += rng.normal(0.0, cfg.sigma_root * scale, (cfg.samples, 3))
            score = _limb_scores(
                skel, cand, roots, s, balls, sel, cameras, fields, unexplained, cfg
            )
            if start_score is None:
                start_score = float(score[0])
            k = int(np.argmin(score))
            if score[k] < best_score:
                best_th, best_rt, best_score = cand[k].copy(), roots[k].copy(), float(score[k])
        gains[name] = start_score - best_score
        if gains[name] >= cfg.min_gain_px:
            theta[d_idx] = best_th[d_idx]
            root = best_rt.copy()
            moved.append(name)
    return SearchResult(theta, root, moved, gains)
