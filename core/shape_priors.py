"""Soft priors of the whole-body shape fit (:mod:`core.shape_fit`) on the metaballs.

* **symmetry** — :func:`mirror_pairs` pairs each left metaball with its right partner
  (and finds the mid-plane ones) about the skeleton's rest-pose sagittal plane;
  :func:`symmetry_rows` are the residuals and Jacobian of "partners have the same radii
  and mirror-image centres, mid-plane metaballs stay on the plane"; :func:`one_sided`
  finds the pairs and mid-plane metaballs whose data lie on one side only, which the
  shape fit holds to the symmetry more tightly;
* **smoothness** — :func:`chain_pairs` lists neighbouring metaballs (consecutive on a
  bone, and across a joint); :func:`smooth_rows` asks neighbours to change alike from
  the start shape.

Unknowns are packed as in :class:`core.shape_problem.ShapeProblem`: radii (M, 3) first,
then the ``n_c`` centre coordinates (M, 3) in their bones' frames, metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .metaballs import Metaballs, world_frames
from .skeleton import Skeleton, bone_frames, forward, joint_positions


@dataclass
class Symmetry:
    """Left/right pairing of metaballs (see :func:`mirror_pairs`).

    Attributes
    ----------
    left, right : (P,) int paired metaballs (left side, right side)
    axis_map : (P, 3) int — the right metaball's axis matching each left axis
    centre : (C,) int metaballs on the mid-plane (trunk, head)
    A : (M, 3, 3) rest-pose bone rotation times scale: world offset ``A @ center0``
    lateral : (3,) unit world axis across the body at rest
    """

    left: np.ndarray
    right: np.ndarray
    axis_map: np.ndarray
    centre: np.ndarray
    A: np.ndarray
    lateral: np.ndarray


def mirror_pairs(skel: Skeleton, balls: Metaballs, s: np.ndarray) -> Symmetry:
    """Pair every ``l_*`` bone's metaballs with the ``r_*`` bone's, in order.

    The mirror plane is the rest pose's (θ = 0) mid-plane, normal to ``l_hip − r_hip``.
    Bones without a partner count as mid-plane bones when they are not sided.
    """
    pose = forward(skel, np.zeros(skel.n_dof), np.zeros(3), s)
    Rb, _ = bone_frames(skel, pose)
    Rb = Rb[0]
    scale = np.where(balls.group >= 0, np.asarray(s, float)[np.maximum(balls.group, 0)], 1.0)
    A = Rb[balls.bone] * scale[:, None, None]
    jl, jr = skel.joint_index("l_hip"), skel.joint_index("r_hip")
    xj = joint_positions(skel, np.zeros(skel.n_dof), np.zeros(3), s)
    lateral = xj[jl] - xj[jr]
    lateral /= np.linalg.norm(lateral)
    mirror = np.eye(3) - 2.0 * np.outer(lateral, lateral)
    Rw = Rb[balls.bone] @ balls.rot
    left, right, amap, centre = [], [], [], []
    names = skel.bone_names
    o = np.einsum("mij,mj->mi", A, balls.center0)  # rest-pose offsets from the bone origin

    def pair(m, mr):
        left.append(m)
        right.append(mr)
        amap.append(np.argmax(np.abs(Rw[mr].T @ mirror @ Rw[m]), axis=0))

    for b, name in enumerate(names):
        on = np.flatnonzero(balls.bone == b)
        if name.startswith("r_"):
            continue
        if name.startswith("l_"):
            other = "r_" + name[2:]
            if other in names:
                for m, mr in zip(
                    on, np.flatnonzero(balls.bone == names.index(other)), strict=False
                ):
                    pair(m, mr)
            continue
        # a mid-line bone: a metaball off the mid-plane pairs with its mirror image on
        # the same bone (e.g. the hip girdle's sides), one on the plane stays on it
        for m in on:
            d = np.linalg.norm(o[on] - mirror @ o[m], axis=1)
            mr = on[np.argmin(d)]
            if mr == m or abs(o[m] @ lateral) < 1e-6:
                centre.append(m)
            elif o[m] @ lateral > 0:
                pair(m, mr)
    return Symmetry(
        np.array(left, int),
        np.array(right, int),
        np.array(amap, int).reshape(-1, 3),
        np.array(centre, int),
        A,
        lateral,
    )


def symmetry_rows(
    sym: Symmetry, M: int, n_c: int, w, radii, centers, w_centre=None
) -> tuple[np.ndarray, np.ndarray]:
    """Residuals and Jacobian (rows, 3M + n_c) of the symmetry prior.

    ``w``: 1/σ of the pairs, a scalar or one per pair (P,); ``w_centre``: 1/σ of the
    mid-plane metaballs' offsets from the plane, a scalar or (C,) (default ``w``, which
    must then be a scalar).
    """
    P, C = len(sym.left), len(sym.centre)
    w_pair = np.broadcast_to(np.asarray(w, float), (P,))
    w_mid = np.broadcast_to(np.asarray(w if w_centre is None else w_centre, float), (C,))
    w3 = np.repeat(w_pair, 3)
    mirror = np.eye(3) - 2.0 * np.outer(sym.lateral, sym.lateral)
    rows = np.arange(3 * P)
    r = [(radii[sym.right[:, None], sym.axis_map] - radii[sym.left]).ravel() * w3]
    J = np.zeros((3 * P, 3 * M + n_c))
    J[rows, (3 * sym.right[:, None] + sym.axis_map).ravel()] = w3
    J[rows, (3 * sym.left[:, None] + np.arange(3)).ravel()] -= w3
    Js = [J]
    if n_c:
        o = np.einsum("mij,mj->mi", sym.A, centers)
        r.append((o[sym.right] - o[sym.left] @ mirror.T).ravel() * w3)
        r.append(o[sym.centre] @ sym.lateral * w_mid)
        Jc = np.zeros((3 * P + C, 3 * M + n_c))
        for k, (m, mr) in enumerate(zip(sym.left, sym.right, strict=True)):
            Jc[3 * k : 3 * k + 3, 3 * M + 3 * mr : 3 * M + 3 * mr + 3] = sym.A[mr] * w_pair[k]
            Jc[3 * k : 3 * k + 3, 3 * M + 3 * m : 3 * M + 3 * m + 3] = (
                -(mirror @ sym.A[m]) * w_pair[k]
            )
        for k, m in enumerate(sym.centre):
            Jc[3 * P + k, 3 * M + 3 * m : 3 * M + 3 * m + 3] = sym.lateral @ sym.A[m] * w_mid[k]
        Js.append(Jc)
    return np.concatenate(r), np.concatenate(Js, axis=0)


def one_sided(
    sym: Symmetry,
    skel: Skeleton,
    balls: Metaballs,
    s: np.ndarray,
    poses: list,
    points: list[np.ndarray],
    ratio: float,
    min_points: int = 20,
) -> tuple[np.ndarray, np.ndarray]:
    """The symmetry pairs and mid-plane metaballs whose data points lie on one side.

    Each point goes to the metaball of strongest field at it (its nearest in the
    metaball's own scaled distance ``d``), at the start shape.  A pair is one-sided when
    its emptier member got fewer than ``ratio`` times its fuller member's points; a
    mid-plane metaball when the points on one side of the sagittal plane through its
    centre are fewer than ``ratio`` times those on the other.  Only with at least
    ``min_points`` on the fuller side: two empty sides say nothing.

    Parameters
    ----------
    sym : the pairing (:func:`mirror_pairs`)
    poses : per frame, the pose (:func:`core.skeleton.forward` of one frame)
    points : per frame, (N_f, 3) world data points, metres
    ratio : in [0, 1] (0: nothing is one-sided)

    Returns
    -------
    pairs : (P,) bool; centres : (C,) bool
    """
    M = len(balls)
    Rb0, _ = bone_frames(skel, forward(skel, np.zeros(skel.n_dof), np.zeros(3), s))
    lat = np.einsum("mji,j->mi", Rb0[0][balls.bone] @ balls.rot, sym.lateral)  # (M, 3)
    side = np.zeros((2, M))
    for pose, x in zip(poses, points, strict=True):
        if not len(x):
            continue
        Rw, cw = world_frames(skel, pose, balls, s)
        y = np.einsum("mji,nmj->nmi", Rw[0], np.asarray(x, float)[:, None] - cw[0][None])
        m = np.argmin(np.sum((y / balls.radii[None]) ** 2, axis=2), axis=1)
        plus = np.einsum("ni,ni->n", y[np.arange(len(m)), m], lat[m]) > 0
        np.add.at(side, (plus.astype(int), m), 1)
    count = side.sum(axis=0)

    def lopsided(a, b):
        hi = np.maximum(a, b)
        return (hi >= min_points) & (np.minimum(a, b) < ratio * hi)

    return (
        lopsided(count[sym.left], count[sym.right]),
        lopsided(side[0, sym.centre], side[1, sym.centre]),
    )


def chain_pairs(balls: Metaballs, skel: Skeleton | None = None) -> np.ndarray:
    """Neighbouring metaballs, (P, 2) int: consecutive ones on one bone
    (``make_metaballs`` lays each bone's out in order from head to tail) and, when
    ``skel`` is given, the last one of a bone with the first one of each child bone."""
    m = np.arange(len(balls) - 1)
    pairs = [np.stack([m, m + 1], axis=1)[balls.bone[:-1] == balls.bone[1:]]]
    if skel is not None:
        for c, p in enumerate(skel.bone_parent):
            on_p, on_c = np.flatnonzero(balls.bone == p), np.flatnonzero(balls.bone == c)
            if p >= 0 and len(on_p) and len(on_c):
                pairs.append(np.array([[on_p[-1], on_c[0]]]))
    return np.concatenate(pairs, axis=0)


def smooth_rows(pairs: np.ndarray, M: int, n_c: int, w: float, radii, centers, radii0, centers0):
    """Residuals and Jacobian (rows, 3M + n_c) of the smoothness prior: neighbours
    change alike from the start shape (radii and centre displacements)."""
    P = len(pairs)
    a, b = pairs[:, 0], pairs[:, 1]
    rows = np.arange(3 * P)
    J = np.zeros((3 * P, 3 * M + n_c))
    J[rows, (3 * b[:, None] + np.arange(3)).ravel()] = w
    J[rows, (3 * a[:, None] + np.arange(3)).ravel()] = -w
    dr = radii - radii0
    r = [(dr[b] - dr[a]).ravel() * w]
    Js = [J]
    if n_c:
        disp = centers - centers0
        r.append((disp[b] - disp[a]).ravel() * w)
        Jc = np.zeros((3 * P, 3 * M + n_c))
        Jc[:, 3 * M :] = J[:, : 3 * M]
        Js.append(Jc)
    return np.concatenate(r), np.concatenate(Js, axis=0)
