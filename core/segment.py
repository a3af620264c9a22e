"""Segmentation of 3-D observations into body parts (paper 1, section 4.1).

Each observed point is assigned to the body part (bone) whose field is strongest at
it in a given posture — the initial posture from the clicks, or the predicted pose
of a frame: ``argmax_b log Σ_{m ∈ b} exp(−2 d_m)`` (eq. 7–8, computed as a
log-sum-exp so that far points keep a ranking).  A point on part b's own surface has
``F_b = 0.5`` while a neighbour's field there is smaller unless the point lies inside
it.  A point farther than ``max_dist`` from every metaball's lone visible surface is
left unassigned (part −1): an outlier or a point of something else.  That distance
is measured radially in each metaball's frame: with ``y`` the point in that frame and
``r = sqrt(d_m)``, ``|y| (1 − r0 / r)`` metres with ``r0 = sqrt(ln 2 / 2)`` (exact for
a sphere, negative inside).

Arrays: ``xyz`` (N, 3) world metres; the result ``part`` (N,) int bone indices.
"""

from __future__ import annotations

import numpy as np

from .metaballs import Metaballs, local_coords, world_frames
from .skeleton import Skeleton, forward
from .vec3 import norm3, sum3


def surface_distance(
    xyz: np.ndarray, Rw: np.ndarray, cw: np.ndarray, visible: np.ndarray
) -> np.ndarray:
    """Approximate distance (N, M) of points to each metaball's rendered ellipsoid.

    Parameters
    ----------
    xyz : (N, 3) world points, metres
    Rw, cw : (M, 3, 3), (M, 3) metaball world frames
    visible : (M, 3) semi-axes of the rendered ellipsoids
        (:attr:`core.metaballs.Metaballs.visible`), metres

    Returns
    -------
    (N, M) metres, negative inside the ellipsoid.
    """
    return _local_surface_distance(local_coords(xyz, Rw, cw), visible)


def _local_surface_distance(y: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """:func:`surface_distance` from the points in the metaballs' frames, y (N, M, 3)."""
    r = np.sqrt(sum3((y / visible[None]) ** 2))
    norm = norm3(y)
    return norm * (1.0 - 1.0 / np.maximum(r, 1e-12))


def segment_points(
    xyz: np.ndarray,
    skel: Skeleton,
    balls: Metaballs,
    theta: np.ndarray,
    root_xyz: np.ndarray,
    s: np.ndarray,
    radii: np.ndarray | None = None,
    max_dist: float = 0.08,
    margin: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Assign each point to the bone of the nearest metaball surface.

    Parameters
    ----------
    xyz : (N, 3) world points, metres
    theta : (n,) radians, root_xyz : (3,) metres, s : (G,) — the posture
    radii : (M, 3) metaball radii (default ``balls.radii``)
    max_dist : points farther than this (metres) from every part get part −1
    margin : an ambiguous point — one whose distance to the surface of a part not
        adjacent to the chosen one (neither its parent nor a child) exceeds the
        distance to the chosen part's surface by less than ``margin`` metres, e.g. a
        point between a hanging hand and the hip — gets part −1 too

    Returns
    -------
    part : (N,) int — bone index into ``skel.bone_names``, −1 unassigned
    dist : (N,) float — distance to the chosen part's surface, metres
    """
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    radii = balls.radii if radii is None else np.asarray(radii, float)
    if len(xyz) == 0:
        return np.zeros(0, dtype=int), np.zeros(0)
    pose = forward(skel, np.asarray(theta, float)[None], np.asarray(root_xyz, float)[None], s)
    Rw, cw = world_frames(skel, pose, balls, s)
    Rw, cw = Rw[0], cw[0]
    y = local_coords(xyz, Rw, cw)
    dist = _local_surface_distance(y, radii * balls.vscale)
    logf = -2.0 * sum3((y / radii[None]) ** 2)  # (N, M)
    bones = np.unique(balls.bone)
    score = np.full((len(xyz), len(bones)), -np.inf)
    for k, b in enumerate(bones):  # log-sum-exp over each bone's metaballs
        lf = logf[:, balls.bone == b]
        top = lf.max(axis=1)
        score[:, k] = top + np.log(np.sum(np.exp(lf - top[:, None]), axis=1))
    best = np.argmax(score, axis=1)
    part = bones[best].astype(int)
    d = np.min(np.where(balls.bone[None, :] == part[:, None], dist, np.inf), axis=1)
    bad = ~np.isfinite(dist.min(axis=1)) | (dist.min(axis=1) > max_dist)
    if margin > 0:
        nb = len(skel.bone_names)
        adj = np.eye(nb, dtype=bool)
        for b, p in enumerate(skel.bone_parent):
            if p >= 0:
                adj[b, p] = adj[p, b] = True
        other = ~adj[part][:, balls.bone]  # (N, M) metaballs of non-adjacent parts
        d_other = np.min(np.where(other, dist, np.inf), axis=1)
        bad |= d_other - d < margin
    part[bad] = -1
    return part, d


def carry_labels(
    part: np.ndarray, ids: np.ndarray | None, known: tuple[np.ndarray, np.ndarray]
) -> tuple[np.ndarray, tuple]:
    """Keep a tracked trajectory in the part it was first assigned to.

    Parameters
    ----------
    part : (N,) int — this frame's segmentation (−1 unassigned)
    ids : (N,) int trajectory ids, or None (nothing to carry)
    known : ``(ids (K,), parts (K,))`` sorted by id — the labels so far

    Returns
    -------
    part : (N,) int — the known label where the trajectory has one, else ``part``
    known : the updated ``(ids, parts)`` with this frame's first assignments added
    """
    if ids is None:
        return part, known
    ids = np.asarray(ids, dtype=np.int64)
    kid, kpart = known
    pos = np.clip(np.searchsorted(kid, ids), 0, max(len(kid) - 1, 0))
    have = (len(kid) > 0) & (kid[pos] == ids) if len(kid) else np.zeros(len(ids), bool)
    out = part.copy()
    out[have] = kpart[pos[have]]
    new = ~have & (part >= 0)
    new_ids, first = np.unique(ids[new], return_index=True)
    kid = np.concatenate([kid, new_ids])
    kpart = np.concatenate([kpart, part[new][first]])
    order = np.argsort(kid, kind="stable")
    return out, (kid[order], kpart[order])


def no_labels() -> tuple[np.ndarray, np.ndarray]:
    """An empty label memory for :func:`carry_labels`."""
    return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=int)
