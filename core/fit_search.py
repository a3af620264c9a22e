"""Global search for a frame's starting pose: which hypothesis explains the points best.

The per-frame least-squares fit (:mod:`core.fitting`) only converges from a start
within a few centimetres of the body: the points are segmented to body parts at the
start (:mod:`core.segment`), and a limb that moved more than the segmentation's reach
since the last frame (a dance kick moves the knee 15–25 cm in 1/25 s) loses its
points and stays behind.  This module scores whole poses without any segmentation,
by how well the body explains the frame's points, so that a few discrete hypotheses
can be compared and a limb placed near its points before the fit:

* :func:`explain_cost` — for H poses at once, the robust (truncated) squared distance
  of every point to the whole body's surface ``Σ_m f_m = 0.5``,
  ``Σ_i min(|d_i|, τ)² / σ²`` (``d_i`` to first order in the log field, as the
  attractor distance of :mod:`core.attractor` with every metaball a member; a point
  inside the body counts by its depth);
* :func:`search_limbs` — per limb (upper arm + forearm, thigh + shin), a grid of
  flexion, abduction and elbow/knee angles around the current pose, the rest of the
  body held; the grid pose of lowest cost plus a weak prior towards the start
  (σ ``sigma_prior``) wins.  Only points outside the rest of the body by more than
  ``explained_m`` and within the limb's reach count (a limb with fewer than 10 such
  points is not moved: a hidden limb stays where the prediction put it), so one limb
  costs (H × N_near × M_limb); the best grid pose is refined on two finer 3×3×3 grids.
  The limbs move greedily (the largest gain first); afterwards (``prune``) each moved
  limb is put back when its move no longer pays, and otherwise weighed against the
  other limbs searched again without it.  On jumps_line3 the right leg — hidden behind
  the left in all three cameras — had taken the points of the left arm that moved in
  the same frame (frame 30), then those of the right hand reappearing 17 cm from the
  body (frame 35), and was thrown up to chest height: MPJPE 62–67 mm, right knee
  208–290 mm; with the prune 23.35 mm, the leg kept through all 50 frames.

With the points' lines of sight (``probes``, :mod:`core.free_space`) both costs add,
per point, the body found between the point and the cameras that measured it: a limb
placed in front of its own points (on the default scene the reappearing forearm, 9 cm
in front of them, frames 25–34) then costs as much as one leaving them unexplained.

Arrays: ``xyz`` (N, 3) world metres; ``theta`` (H, n) radians; ``root`` (H, 3) metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .attractor import LN_T
from .field_kernel import log_field
from .free_space import DEPTHS, Probes, occlusion_cost
from .metaballs import Metaballs, world_frames
from .skeleton import Skeleton, forward, joint_positions
from .vec3 import norm3

_LEG_GRID = (
    ("hip_x", (-75, -50, -25, 0, 25, 50, 75)),
    ("hip_y", (-30, 0, 30)),
    ("knee_x", (-60, -30, 0, 30, 60)),
)
_ARM_GRID = (
    ("shoulder_x", (-75, -50, -25, 0, 25, 50, 75)),
    ("shoulder_y", (-50, -25, 0, 25, 50)),
    ("elbow_x", (-60, -30, 0, 30, 60)),
)


def _limb(side: str, bones: tuple, root_joint: str, tail_joint: str, grid: tuple) -> tuple:
    return (
        tuple(side + b for b in bones),
        side + root_joint,
        side + tail_joint,
        tuple((side + d, g) for d, g in grid),
    )


#: Limbs searched by :func:`search_limbs`: name -> (bones moved, root joint, tail
#: joint, grid DOFs with their offsets in degrees around the start).
LIMBS = {
    f"{side}{name}": _limb(side, *spec)
    for side in ("l_", "r_")
    for name, spec in (
        ("leg", (("hip", "knee", "ankle"), "hip", "ankle", _LEG_GRID)),
        ("arm", (("shoulder", "elbow", "wrist"), "shoulder", "wrist", _ARM_GRID)),
    )
}


def _limb_move(
    xyz,
    skel,
    balls,
    s,
    radii,
    theta,
    root,
    limb,
    tau,
    sigma,
    sigma_prior,
    explained_m,
    min_points: int = 10,
    max_points: int = 200,
    probes: Probes | None = None,
) -> tuple[float, np.ndarray | None]:
    """Best grid pose of one limb: (cost decrease, theta (n,)) or (0, None)."""
    bones, root_joint, tail_joint, grid = limb
    on = np.isin(balls.bone, [skel.bone_index(b) for b in bones])
    pose = forward(skel, theta[None], root[None], s)
    Rw, cw = world_frames(skel, pose, balls, s)
    L_rest, g_rest = log_field(xyz, Rw[:, ~on], cw[:, ~on], radii[~on])
    L_self, g_self = log_field(xyz, Rw[:, on], cw[:, on], radii[on])
    d_rest = _distance(L_rest, g_rest)[0]
    jx = joint_positions(skel, theta, root, s)
    base = jx[skel.joint_index(root_joint)]
    reach = np.linalg.norm(jx[skel.joint_index(tail_joint)] - base) * 1.15 + 0.1
    in_reach = np.linalg.norm(xyz - base, axis=1) < reach
    near = (d_rest < -explained_m) & in_reach
    if probes is not None:
        # free space: also the points the limb buries or hides from their cameras — a
        # hidden limb that swung into the other leg is moved out of it
        inside = _distance(*_combine(L_rest, g_rest, L_self, g_self))[0] > explained_m
        # a probe reaches at most max(DEPTHS) from its point: farther from the limb's
        # surface, the limb hides nothing of it
        close = _distance(L_self, g_self)[0] > -(max(DEPTHS) + 0.02)
        cand = np.flatnonzero(in_reach & close & ~near & ~inside)
        if len(cand):
            pc = probes.select(cand)
            d_self = _distance(*log_field(pc.xyz.reshape(-1, 3), Rw[:, on], cw[:, on], radii[on]))[
                0
            ]
            hides = np.zeros(len(xyz), bool)
            hides[cand] = occlusion_cost(d_self.reshape(pc.valid.shape), pc.valid) > 0
            inside |= hides
        near |= inside & in_reach
    if near.sum() < min_points:
        return 0.0, None
    sel = np.nonzero(near)[0]
    if len(sel) > max_points:  # an even subsample keeps the grid's cost bounded
        sel = sel[np.linspace(0, len(sel) - 1, max_points).astype(int)]
    near = np.zeros(len(xyz), bool)
    near[sel] = True
    x = xyz[near]
    Lr, gr = L_rest[:, near], g_rest[:, near]
    if probes is not None:  # the near points' lines of sight, (N_near·K, 3)
        pr = probes.select(near)
        px = pr.xyz.reshape(-1, 3)
        Lp, gp = log_field(px, Rw[:, ~on], cw[:, ~on], radii[~on])

    def cost(th):
        pose = forward(skel, th, np.repeat(root[None], len(th), axis=0), s)
        Rw, cw = world_frames(skel, pose, balls, s)
        d = _distance(*_combine(Lr, gr, *log_field(x, Rw[:, on], cw[:, on], radii[on])))
        c = _rho(d, tau, sigma).sum(axis=1)
        if probes is not None:
            dp = _distance(*_combine(Lp, gp, *log_field(px, Rw[:, on], cw[:, on], radii[on])))
            c = c + occlusion_cost(
                dp.reshape(len(th), *pr.valid.shape), pr.valid, tau=tau, sigma=sigma
            ).sum(axis=1)
        return c

    cost0 = float(cost(theta[None])[0])

    best, best_cost = grid_search(skel, theta, grid, cost, cost0, 1.0 / sigma_prior**2)
    if best is theta:
        return 0.0, None
    return cost0 - best_cost, best


@dataclass
class SearchResult:
    """Outcome of :func:`search_limbs`.

    Attributes
    ----------
    theta : (n,) radians — the start with every searched limb at its best grid pose
    cost_before, cost_after : explain cost (see :func:`explain_cost`) of the whole body
    moved : list of str — limbs whose best grid pose is not the start
    """

    theta: np.ndarray
    cost_before: float
    cost_after: float
    moved: list


def _combine(La, ga, Lb, gb) -> tuple[np.ndarray, np.ndarray]:
    """Log field and gradient of the sum of two fields given as ``(L, ∇L)``."""
    L = np.logaddexp(La, Lb)
    wa, wb = np.exp(La - L), np.exp(Lb - L)
    return L, wa[..., None] * ga + wb[..., None] * gb


def _distance(L: np.ndarray, g: np.ndarray, g_min: float = 2.0) -> np.ndarray:
    """Signed distance to the surface ``Σ f = 0.5`` to first order,
    ``(L − ln 0.5) / max(|∇L|, g_min)`` metres (positive inside), as in
    :mod:`core.attractor`."""
    return (L - LN_T) / np.maximum(norm3(g), g_min)


def _rho(d: np.ndarray, tau: float, sigma: float) -> np.ndarray:
    return np.minimum(np.abs(d), tau) ** 2 / sigma**2


def keeps_points(
    xyz: np.ndarray,
    skel: Skeleton,
    balls: Metaballs,
    s: np.ndarray,
    radii: np.ndarray,
    root: np.ndarray,
    tau: float = 0.05,
    probes: Probes | None = None,
    slack: float = 0.1,
):
    """A veto for the silhouette limb search in a frame with points
    (:func:`core.silhouette_search.search_limbs_silhouette` ``allowed``): a move from
    ``theta`` (n,) to ``candidate`` (n,), the root (3,) held, is allowed when the body
    explains the points ``xyz`` (N, 3) no worse (:func:`explain_cost`) by more than
    ``slack`` — a tenth of one point one σ (1 cm) further off; a limb taken off its
    points costs tens to thousands.  The silhouettes then place a limb the tracker lost,
    but do not take a limb off its points.

    Without the slack a limb with no points could not move: the points by its root
    (the pelvis's, beside a thigh) shift their cost by a few thousandths as it turns,
    and a kicked leg the silhouettes showed 6,400 px better was vetoed by 0.003.  Over
    4 click sets (``bench.fit_spread``) the walk's median MPJPE 14.7 → 13.7 mm with it,
    jumps_line3 15.3 → 15.3 (1.0 gives 15.6); see docs/design.md.
    """

    def allowed(theta, candidate):
        c = explain_cost(
            xyz,
            skel,
            balls,
            s,
            radii,
            np.stack([theta, candidate]),
            np.stack([root, root]),
            tau,
            probes=probes,
        )
        return bool(c[1] <= c[0] + slack)

    return allowed


def explain_cost(
    xyz: np.ndarray,
    skel: Skeleton,
    balls: Metaballs,
    s: np.ndarray,
    radii: np.ndarray,
    theta: np.ndarray,
    root: np.ndarray,
    tau: float = 0.05,
    sigma: float = 0.01,
    chunk: int = 16,
    probes: Probes | None = None,
) -> np.ndarray:
    """Robust cost (H,) of H poses: how badly the body leaves the points unexplained.

    Parameters
    ----------
    xyz : (N, 3) world points, metres
    theta : (H, n) radians; root : (H, 3) metres
    tau : truncation of a point's distance, metres (an outlier or a point of another
        thing costs at most ``(tau / sigma)²``)
    sigma : distance scale, metres
    probes : the points' lines of sight (:func:`core.free_space.probes`), optional:
        adds :func:`core.free_space.occlusion_cost` per point

    Returns
    -------
    (H,) ``Σ_i min(|d_i|, tau)² / sigma²`` with ``d_i`` the first-order distance of
    point i to the body surface (positive inside, counted by its magnitude), plus the
    occlusion cost of the probes.
    """
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    theta = np.atleast_2d(np.asarray(theta, float))
    root = np.atleast_2d(np.asarray(root, float))
    out = np.zeros(len(theta))
    if not len(xyz) and (probes is None or not len(probes)):
        return out
    for a in range(0, len(theta), chunk):
        pose = forward(skel, theta[a : a + chunk], root[a : a + chunk], s)
        Rw, cw = world_frames(skel, pose, balls, s)
        if len(xyz):
            out[a : a + chunk] = _rho(_distance(*log_field(xyz, Rw, cw, radii)), tau, sigma).sum(
                axis=1
            )
        if probes is None or not len(probes):
            continue
        for h in range(len(Rw)):  # K probes per point: one pose at a time bounds memory
            dp = _distance(
                *log_field(probes.xyz.reshape(-1, 3), Rw[h : h + 1], cw[h : h + 1], radii)
            )
            out[a + h] += occlusion_cost(
                dp.reshape(probes.valid.shape), probes.valid, tau=tau, sigma=sigma
            ).sum()
    return out


def explain_distance(
    xyz: np.ndarray,
    skel: Skeleton,
    balls: Metaballs,
    s: np.ndarray,
    radii: np.ndarray,
    theta: np.ndarray,
    root: np.ndarray,
) -> np.ndarray:
    """Distance (N,) metres of each point to the body surface ``Σ f = 0.5`` in one pose
    (first order, positive inside); the ``d_i`` of :func:`explain_cost`."""
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    pose = forward(skel, np.asarray(theta, float)[None], np.asarray(root, float)[None], s)
    Rw, cw = world_frames(skel, pose, balls, s)
    return _distance(*log_field(xyz, Rw, cw, radii))[0]


def _grid(skel: Skeleton, theta0: np.ndarray, grid) -> tuple[np.ndarray, np.ndarray]:
    """Hypotheses (H, n) around ``theta0`` over the grid's DOFs, clipped to the limits;
    returns them and the DOF indices.  A grid entry ``(DOF, offsets, values)`` adds
    the absolute ``values`` (degrees) to that DOF's offsets."""
    idx = np.array([skel.dof_index(e[0]) for e in grid])
    axes = []
    for k, (_, g, *values) in zip(idx, grid, strict=True):
        o = np.radians(np.asarray(g, float))
        if values:
            o = np.union1d(o, np.radians(np.asarray(values[0], float)) - theta0[k])
        axes.append(o)
    offs = np.meshgrid(*axes, indexing="ij")
    offs = np.stack([o.ravel() for o in offs], axis=1)  # (H, k)
    th = np.repeat(theta0[None], len(offs), axis=0)
    th[:, idx] = np.clip(theta0[idx][None] + offs, skel.dof_lo[idx], skel.dof_hi[idx])
    return th, idx


def grid_search(
    skel: Skeleton,
    theta: np.ndarray,
    grid,
    cost,
    cost0: float,
    prior_weight: float,
    levels: int = 3,
) -> tuple[np.ndarray, float]:
    """Lowest-cost pose of one limb over a grid around ``theta``, then finer grids.

    Parameters
    ----------
    theta : (n,) start pose, radians
    grid : ((DOF name, offsets in degrees[, absolute values in degrees]), ...) — see
        :data:`LIMBS`
    cost : callable, poses (H, n) -> (H,) costs
    cost0 : the cost of ``theta`` itself
    prior_weight : weight of the prior towards the start, ``prior_weight · Σ Δθ²``
        over the grid DOFs (radians²)
    levels : the grid, then ``levels - 1`` 3×3×… grids of half, quarter … its spacing
        about the best pose so far

    Returns
    -------
    (best pose — ``theta`` itself (the same object) when nothing beats it — and its cost)
    """
    best, best_cost = theta, cost0
    for level in range(levels):
        if level == 0:
            th, idx = _grid(skel, best, grid)
        else:
            step = [np.diff(e[1]).min() / 2**level for e in grid]
            th, idx = _grid(
                skel, best, [(e[0], (-st, 0.0, st)) for e, st in zip(grid, step, strict=True)]
            )
        c = cost(th) + prior_weight * np.sum((th[:, idx] - theta[idx][None]) ** 2, axis=1)
        k = int(np.argmin(c))
        if c[k] < best_cost - 1e-9:
            best, best_cost = th[k].copy(), float(c[k])
    return best, best_cost


def search_limbs(
    xyz: np.ndarray,
    skel: Skeleton,
    balls: Metaballs,
    s: np.ndarray,
    radii: np.ndarray,
    theta0: np.ndarray,
    root: np.ndarray,
    limbs: tuple | None = None,
    tau: float = 0.05,
    sigma: float = 0.01,
    sigma_prior: float = 0.6,
    explained_m: float = 0.01,
    rounds: int = 2,
    min_gain: float = 0.0,
    prune: bool = True,
    probes: Probes | None = None,
) -> SearchResult:
    """Place each limb at the grid pose that best explains the points near it.

    Parameters
    ----------
    xyz : (N, 3) world points of the frame, metres
    theta0 : (n,) start pose, radians; root : (3,) metres
    limbs : names of :data:`LIMBS` to search (default all four)
    tau, sigma : see :func:`explain_cost`
    sigma_prior : σ (radians) of the weak prior towards the start on the grid DOFs: a
        move must explain more points than it costs, so a limb without points stays
    explained_m : only points outside the rest of the body by more than this count
    min_gain : a move must lower the cost by more than this (a few outliers near a
        limb do not move it)
    rounds : moves per limb at most; each move goes to the limb whose best grid pose
        lowers the cost most (so a limb takes its own points before another can)
    prune : afterwards, each moved limb is put back when the cost then rises by no more
        than ``min_gain``; otherwise the other limbs are searched again from there, and
        their result stands when it explains the points as well, or within
        ``min_gain`` while moving less (the limb's move was not needed)
    probes : the points' lines of sight (:func:`core.free_space.probes`), optional:
        every cost then counts the body in front of a point as well

    Returns
    -------
    SearchResult
    """
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    theta = np.asarray(theta0, float).copy()
    root = np.asarray(root, float).reshape(3)
    names = tuple(LIMBS) if limbs is None else tuple(limbs)
    before = float(
        explain_cost(
            xyz, skel, balls, s, radii, theta[None], root[None], tau, sigma, probes=probes
        )[0]
    )
    if len(xyz) == 0:
        return SearchResult(theta, before, before, [])

    def greedy(theta, allowed):
        """Move the limbs of ``allowed``, the largest gain first: (theta, moved, cost)."""
        moved: list[str] = []
        for _ in range(rounds * len(allowed)):
            best_gain, best_theta, best_name = min_gain, None, None
            for name in allowed:
                gain, th = _limb_move(
                    xyz,
                    skel,
                    balls,
                    s,
                    radii,
                    theta,
                    root,
                    LIMBS[name],
                    tau,
                    sigma,
                    sigma_prior,
                    explained_m,
                    probes=probes,
                )
                if gain > best_gain:
                    best_gain, best_theta, best_name = gain, th, name
            if best_theta is None:
                break
            theta = best_theta
            if best_name not in moved:
                moved.append(best_name)
        cost = float(
            explain_cost(
                xyz, skel, balls, s, radii, theta[None], root[None], tau, sigma, probes=probes
            )[0]
        )
        return theta, moved, cost

    grid_dofs = [skel.dof_index(d) for m in names for d, _ in LIMBS[m][3]]

    def motion(th):  # how far the limbs moved from the start, rad²
        return float(np.sum((th[grid_dofs] - theta0[grid_dofs]) ** 2))

    theta, moved, after = greedy(theta, names)
    if prune:
        # a move that no longer pays, or one the others can do without (they explain
        # the same points within min_gain, moving less), is undone: a hidden leg does
        # not keep the points of a hand that reappeared because its grid gained more
        for name in list(moved):
            back = theta.copy()
            idx = [skel.dof_index(d) for d, _ in LIMBS[name][3]]
            back[idx] = theta0[idx]
            others = tuple(m for m in names if m != name)
            cost_back = float(
                explain_cost(
                    xyz, skel, balls, s, radii, back[None], root[None], tau, sigma, probes=probes
                )[0]
            )
            if cost_back <= after + min_gain:  # the move no longer pays: put back
                theta, after, names = back, cost_back, others
                moved.remove(name)
                continue
            alt, alt_moved, cost = greedy(back, others)
            if cost <= after + min_gain and (cost <= after or motion(alt) < motion(theta)):
                theta, after = alt, cost
                moved = [m for m in moved if m != name]
                moved += [m for m in alt_moved if m not in moved]
                names = others
    return SearchResult(theta, before, after, moved)


#: Offsets (metres) tried by :func:`recentred_starts` along two horizontal axes about
#: the shift that carries the body along with its points' median.
RECENTRE_OFFSETS = (-0.2, -0.1, 0.0, 0.1, 0.2)


def recentred_starts(
    xyz: np.ndarray,
    q: np.ndarray,
    ref_xyz: np.ndarray,
    ref_root: np.ndarray,
    up: np.ndarray,
    offsets: tuple = RECENTRE_OFFSETS,
) -> np.ndarray:
    """Starts for re-finding a body that the prediction has lost: ``q`` moved onto the
    points, across the floor.

    After frames that could not be fitted (the limbs moved faster than the prediction,
    clutter, a gap in the points) the prediction stays where the body was last seen
    while the person moves on; the per-frame fit then finds most points far from the
    body and fails again, frame after frame.  These candidates keep ``q``'s angles and
    its root's height (along ``up``), and move its root across the floor to where the
    last fitted frame's root was, moved as far as the points' median moved since (the
    points cover only the sides the cameras see, so their median is no estimate of the
    body's centre, but its motion is one of the body's; its vertical motion is not,
    as the parts in view change), plus every combination of ``offsets`` along two
    horizontal axes; the caller keeps the one that explains the points best
    (:func:`explain_cost`).

    Parameters
    ----------
    xyz : (N, 3) world points of the frame, metres
    q : (n + 3,) pose: angles (radians), then the root (world metres)
    ref_xyz : (M, 3) points of the last fitted frame, metres
    ref_root : (3,) its fitted root, metres
    up : (3,) the body's upright direction in the world (e.g. pelvis to neck at the
        clicked frame); normalised here
    offsets : offsets along two axes perpendicular to ``up``, metres

    Returns
    -------
    (len(offsets)², n + 3) candidate poses (none without points in either frame)
    """
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    ref_xyz = np.asarray(ref_xyz, float).reshape(-1, 3)
    q = np.asarray(q, float)
    n = len(q) - 3
    if not len(xyz) or not len(ref_xyz):
        return np.zeros((0, n + 3))
    up = np.asarray(up, float) / np.linalg.norm(up)
    a = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(up, a)
    move = np.asarray(ref_root, float) + np.median(xyz, axis=0) - np.median(ref_xyz, axis=0)
    move -= q[n:]
    move -= (move @ up) * up  # across the floor only
    oa, ob = np.meshgrid(offsets, offsets, indexing="ij")
    out = np.repeat(q[None], oa.size, axis=0)
    out[:, n:] = q[n:] + move + oa.reshape(-1, 1) * a + ob.reshape(-1, 1) * b
    return out
