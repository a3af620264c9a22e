"""Limb search against the foreground masks: the silhouette counterpart of :mod:`core.fit_search`.

With contours alone (bare skin: the tracker finds no points) a limb is seen only by
its share of the *outer* occluding contour (:func:`core.contour_pairs.outer_rim`).
An arm swinging in front of the trunk has none — its parts are held as hidden — and
when its hand comes out of the silhouette again it is often further from the model's
rim than the contour pairing reaches (``max_dist_px``), so the hold keeps it where
it went in.  On the walk with the ``skin`` look (line3) the wrists ended 225–235 mm
off, the rest of the body 17–54 mm.

Here every limb is placed, as :func:`core.fit_search.search_limbs` does with points,
at the grid pose that best explains the frame's foreground (the arms' grids with the
upper arm's twist as well, :data:`SILHOUETTE_LIMBS`):

* each metaball's visible ellipsoid (:func:`core.contour_obs.body_ellipsoids`) is
  projected to an image ellipse by the camera's Jacobian at its centre (weak
  perspective per metaball; tested against the ray-cast outline, IoU > 0.95);
* on a grid of pixels (every ``step`` px) around the person, the foreground that the
  rest of the body leaves unexplained counts for the limb where the limb covers it,
  background the limb covers against it (× ``w_background``); foreground the rest of
  the body already covers is neutral, so an arm over the trunk costs nothing;
* a weak prior towards the start (σ ``sigma_prior`` per grid DOF, ``prior_px`` pixels
  of area per σ²) keeps a limb without evidence where it was.

With it (and the head and neck left out of the contours) the skin walk fits to 29.0 mm
instead of 71.2 mm.  The same projection gives :func:`silhouette_iou` (the sequence fit
marks a contours-alone frame below ``min_silhouette_iou`` diverged),
:func:`silhouette_disagreement` and :func:`recentre_root` (a lost body moved back onto
the foreground before a second fit).

Arrays: ``theta`` (n,) radians; ``root`` (3,) metres; image points ``(u, v)`` pixels
(:mod:`core.camera`); masks (H, W) bool.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera import Camera, camera_project_jacobians
from .contour_obs import body_ellipsoids
from .ellipse_kernel import background_area, covered, image_covariances
from .fit_search import LIMBS, grid_search
from .metaballs import Metaballs, world_frames
from .skeleton import Skeleton, forward, joint_positions

#: Upper-arm twist offsets (degrees) the silhouette search adds to the arm grids of
#: :data:`core.fit_search.LIMBS`.  With points the per-frame fit sets the twist; with
#: contours alone a bent arm's forearm swings about the upper arm unseen by the
#: contour pairing once it has left its reach, and only the twist puts it back (see
#: :data:`SILHOUETTE_LIMBS`).
ARM_TWIST_DEG = (-60, -30, 0, 30, 60)

#: The limbs the silhouette search moves: :data:`core.fit_search.LIMBS`, the arms with
#: the upper arm's twist (``shoulder_z``, :data:`ARM_TWIST_DEG`) as a fourth grid DOF.
#: On walk_ortho3 the left forearm, bent, had swung forward about the upper arm (the
#: truth's arm is 54° further in twist) where the three-DOF grid could not follow.
#: Contours alone, 50 frames: walk_ortho3 (the tracker finds no points on that rig)
#: 34.1 -> 25.9 mm, the left wrist in frames 10-19 9-14 mm (was 130-344 mm);
#: walk_skin_line3 35.5 -> 28.7 mm; but jumps_line3 41.4 -> 49.6 mm (both legs lost
#: in frames 21-29 of the jump).  The fit with contours alone is sensitive to the
#: search's details: twist offsets of ±50 gave walk_ortho3 38.8 mm, seven offsets of
#: 25° 29.1 mm and walk_skin_line3 59.4 mm (legs lost from frame 37).  The search
#: takes about twice as long.
SILHOUETTE_LIMBS = {
    name: (
        bones,
        root_joint,
        tail_joint,
        grid + ((name[:2] + "shoulder_z", ARM_TWIST_DEG),) if name.endswith("arm") else grid,
    )
    for name, (bones, root_joint, tail_joint, grid) in LIMBS.items()
}

#: Absolute flexions (degrees) the search tries for the hinges with ``unfold``, beside
#: the offsets around the fit: straight, half and right-angled.  A shin or forearm
#: folded onto its parent (knee 164°, elbow -151° in dance_ortho3's lost draws) lies
#: inside the parent's outline, where it costs nothing, and the true segment's
#: foreground is more than the ±60° offsets (two rounds: 120°) away.
UNFOLD_DEG = {"knee_x": (0.0, 45.0, 90.0), "elbow_x": (0.0, -45.0, -90.0)}


#: A hinge flexed further than this (degrees) counts as folded for ``unfold``.
FOLDED_DEG = 120.0


def unfolded(skel: Skeleton, limb: tuple, theta: np.ndarray) -> tuple:
    """A :data:`SILHOUETTE_LIMBS` entry with :data:`UNFOLD_DEG`'s absolute flexions
    added to the grid of its hinge where ``theta`` (n,) has it folded (beyond
    :data:`FOLDED_DEG`); the search then also looks for the limb's foreground as far as
    the straightened limb reaches.  Unchanged when the hinge is not folded."""
    bones, root_joint, tail_joint, grid = limb
    grid = tuple(
        (d, g, UNFOLD_DEG[d[2:]])
        if d[2:] in UNFOLD_DEG and abs(theta[skel.dof_index(d)]) > np.radians(FOLDED_DEG)
        else (d, g)
        for d, g in grid
    )
    return bones, root_joint, tail_joint, grid


def folds(skel: Skeleton, theta0: np.ndarray, theta: np.ndarray) -> bool:
    """Whether ``theta`` (n,) folds a knee or elbow (beyond :data:`FOLDED_DEG`) that
    ``theta0`` (n,) has unfolded: a search's move worth weighing against the search
    without it (``no_fold``)."""
    grid = tuple((d, ()) for _, _, _, g in SILHOUETTE_LIMBS.values() for d, *_ in g)
    return bool(_new_folds(skel, grid, np.asarray(theta0, float), np.asarray(theta)[None])[0])


@dataclass
class MaskGrid:
    """Pixels sampled from one camera's foreground mask around the person.

    Attributes
    ----------
    uv : ndarray, shape (G, 2)
        Pixel centres on a grid of ``step`` px over the mask's bounding box plus a
        margin, pixels.
    fg : ndarray, shape (G,), bool
        Foreground at those pixels.
    step : int
        Grid spacing, pixels (each sample stands for step² pixels).
    """

    uv: np.ndarray
    fg: np.ndarray
    step: int


def mask_grid(mask: np.ndarray, step: int = 2, margin_px: int = 40) -> MaskGrid:
    """:class:`MaskGrid` of a foreground mask (H, W) bool; empty when the mask is."""
    mask = np.asarray(mask, bool)
    vs, us = np.nonzero(mask)
    if not len(us):
        return MaskGrid(np.zeros((0, 2)), np.zeros(0, bool), step)
    h, w = mask.shape
    u0, u1 = max(us.min() - margin_px, 0), min(us.max() + margin_px, w - 1)
    v0, v1 = max(vs.min() - margin_px, 0), min(vs.max() + margin_px, h - 1)
    gu, gv = np.meshgrid(np.arange(u0, u1 + 1, step), np.arange(v0, v1 + 1, step))
    uv = np.stack([gu.ravel(), gv.ravel()], axis=1)
    return MaskGrid(uv.astype(float), mask[uv[:, 1], uv[:, 0]], step)


def image_ellipses(
    camera: Camera, centers: np.ndarray, axes: np.ndarray, radii: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Image ellipses of ellipsoids: centres (M, 2) px and inverse shapes (M, 2, 2).

    A pixel ``u`` is inside ellipse m when ``(u - mu_m)ᵀ S_m (u - mu_m) <= 1``, with
    ``S_m = (J A diag(r²) Aᵀ Jᵀ)⁻¹`` and ``J`` (2, 3) the projection's Jacobian at the
    ellipsoid's centre.  ``axes`` (M, 3, 3) has the world axes as columns, ``radii``
    (M, 3) metres.  Ellipsoids behind the camera get a zero shape (cover nothing).
    """
    centers = np.asarray(centers, float).reshape(-1, 3)
    uv, _, J = camera_project_jacobians(camera, centers)
    cov2 = image_covariances(axes, radii, J)
    det = cov2[:, 0, 0] * cov2[:, 1, 1] - cov2[:, 0, 1] * cov2[:, 1, 0]
    z = camera.to_camera(centers)[:, 2]
    ok = np.all(np.isfinite(uv), axis=1) & (z > 1e-6) & (det > 1e-12)
    inv = np.zeros_like(cov2)
    d = np.where(ok, det, 1.0)
    inv[:, 0, 0], inv[:, 1, 1] = cov2[:, 1, 1] / d, cov2[:, 0, 0] / d
    inv[:, 0, 1] = inv[:, 1, 0] = -cov2[:, 0, 1] / d
    inv[~ok] = 0.0
    return np.where(ok[:, None], uv, 0.0), inv


def _body_coverage(skel, balls, theta, root, s, cameras, grids):
    """Per camera the body's coverage (G,) bool of its grid's pixels (None: empty grid)."""
    centers, axes, radii, _ = body_ellipsoids(skel, theta, root, s, balls)
    out = []
    for cam, g in zip(cameras, grids, strict=True):
        if not len(g.fg):
            out.append(None)
            continue
        mu, inv = image_ellipses(cam, centers, axes, radii)
        out.append(covered(g.uv, mu, inv))
    return out


def silhouette_disagreement(
    skel: Skeleton,
    balls: Metaballs,
    theta: np.ndarray,
    root: np.ndarray,
    s: np.ndarray,
    cameras: list[Camera],
    grids: list[MaskGrid],
) -> float:
    """Pixels (summed over cameras) where the body's projection and the foreground
    disagree (either covers what the other does not), counted on the grids."""
    cover = _body_coverage(skel, balls, theta, root, s, cameras, grids)
    return float(
        sum(
            np.sum(c != g.fg) * g.step**2
            for c, g in zip(cover, grids, strict=True)
            if c is not None
        )
    )


def silhouette_iou(
    skel: Skeleton,
    balls: Metaballs,
    theta: np.ndarray,
    root: np.ndarray,
    s: np.ndarray,
    cameras: list[Camera],
    grids: list[MaskGrid],
) -> np.ndarray:
    """Intersection over union (C,) of the body's projection and each camera's foreground
    on its grid (NaN for a camera with an empty grid).  Only the pixels of the grid count:
    the foreground's bounding box plus its margin."""
    cover = _body_coverage(skel, balls, theta, root, s, cameras, grids)
    return np.array(
        [
            np.nan if c is None else float(np.sum(c & g.fg)) / max(float(np.sum(c | g.fg)), 1.0)
            for c, g in zip(cover, grids, strict=True)
        ]
    )


def recentre_root(
    skel: Skeleton,
    balls: Metaballs,
    theta: np.ndarray,
    root: np.ndarray,
    s: np.ndarray,
    cameras: list[Camera],
    grids: list[MaskGrid],
    iterations: int = 3,
) -> np.ndarray:
    """The root (3,) moved so that the body's projection is centred on the foreground.

    Per camera with a mask the image shift between the foreground's centroid and the
    centroid of the body's coverage (the root's projection when the body covers none
    of the grid), mapped to a world shift by the least squares of the cameras'
    projection Jacobians at the root (2 per camera; at least two cameras needed, else
    the root is returned unchanged).  A coarse re-localisation for a body the contour
    fit lost: the contours then refine it.
    """
    root = np.asarray(root, float).copy()
    for _ in range(iterations):
        cover = _body_coverage(skel, balls, theta, root, s, cameras, grids)
        rows, rhs = [], []
        for cam, g, c in zip(cameras, grids, cover, strict=True):
            if c is None or not g.fg.any():
                continue
            uv_r, _, J = camera_project_jacobians(cam, root[None])
            if not np.all(np.isfinite(uv_r)):
                continue
            at = g.uv[c].mean(axis=0) if c.any() else uv_r[0]
            rows.append(J[0])
            rhs.append(g.uv[g.fg].mean(axis=0) - at)
        if len(rows) < 2:
            break
        A, b = np.vstack(rows), np.concatenate(rhs)
        step = np.linalg.lstsq(A, b, rcond=None)[0]
        root += step
        if np.linalg.norm(step) < 1e-3:
            break
    return root


@dataclass
class SilhouetteSearch:
    """Outcome of :func:`search_limbs_silhouette`.

    Attributes
    ----------
    theta : ndarray, shape (n,)
        The start with every moved limb at its best grid pose, radians.
    moved : list of str
        Limbs (names of :data:`core.fit_search.LIMBS`) whose pose changed.
    gain_px : float
        Decrease of the search cost (pixels, prior included) over all moves.
    """

    theta: np.ndarray
    moved: list
    gain_px: float


def _new_folds(skel: Skeleton, grid, theta: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """(H,) bool: ``poses`` (H, n) that fold a hinge of the limb's ``grid`` (a knee or an
    elbow flexed beyond :data:`FOLDED_DEG`) that ``theta`` (n,) has unfolded."""
    hinges = [
        k
        for k in (skel.dof_index(e[0]) for e in grid if e[0][2:] in UNFOLD_DEG)
        if abs(theta[k]) <= np.radians(FOLDED_DEG)
    ]
    if not hinges:
        return np.zeros(len(poses), bool)
    return np.any(np.abs(poses[:, hinges]) > np.radians(FOLDED_DEG), axis=1)


def _limb_gain(
    skel,
    balls,
    s,
    theta,
    root,
    limb,
    cameras,
    masks,
    sigma_prior,
    prior_px,
    w_background,
    step,
    no_fold=False,
):
    """Best grid pose of one limb against the masks: ``(gain px, theta)`` or (0, None).
    ``no_fold``: poses that fold one of its unfolded hinges are left out."""
    bones, root_joint, tail_joint, grid = limb
    on = np.isin(balls.bone, [skel.bone_index(b) for b in bones])
    if not on.any():
        return 0.0, None
    centers, axes, radii, _ = body_ellipsoids(skel, theta, root, s, balls)
    jx = joint_positions(skel, theta, root, s)
    base = jx[skel.joint_index(root_joint)]
    jr = jx
    hinges = [skel.dof_index(e[0]) for e in grid if len(e) > 2]
    if hinges:  # unfolding: the reach of the limb straightened, not of the folded one
        straight = np.asarray(theta, float).copy()
        straight[hinges] = 0.0
        jr = joint_positions(skel, straight, root, s)
    reach = (
        np.linalg.norm(jr[skel.joint_index(tail_joint)] - jr[skel.joint_index(root_joint)]) * 1.15
        + 0.1
    )
    views = []
    for cam, mask in zip(cameras, masks, strict=True):
        if mask is None:
            continue
        b_uv = cam.project(base[None])[0]
        z = cam.to_camera(base[None])[0, 2]
        if not (np.all(np.isfinite(b_uv)) and z > 1e-6):
            continue
        r_px = reach * cam.K[0, 0] / z
        h, w = mask.shape
        gu, gv = np.meshgrid(
            np.arange(max(b_uv[0] - r_px, 0), min(b_uv[0] + r_px, w - 1), step),
            np.arange(max(b_uv[1] - r_px, 0), min(b_uv[1] + r_px, h - 1), step),
        )
        uv = np.stack([gu.ravel(), gv.ravel()], axis=1)
        uv = uv[np.sum((uv - b_uv) ** 2, axis=1) <= r_px**2]
        uv = uv[mask[np.rint(uv[:, 1]).astype(int), np.rint(uv[:, 0]).astype(int)]]
        if not len(uv):
            continue
        mu, inv = image_ellipses(cam, centers[~on], axes[~on], radii[~on])
        unexplained = uv[~covered(uv, mu, inv)]  # foreground the rest leaves to the limb
        if len(unexplained):
            views.append((cam, mask, unexplained))
    if not views:
        return 0.0, None
    r_on = radii[on]
    on_dofs = skel.bone_dof[balls.bone[on]]  # the limb's frames alone are posed

    def score(th):
        """(H,) unexplained foreground covered minus weighted background, pixels."""
        pose = forward(skel, th, np.repeat(root[None], len(th), axis=0), s, dofs=on_dofs)
        Rw, cw = world_frames(skel, pose, balls, s, which=on)
        H, E = len(th), int(on.sum())
        total = np.zeros(H)
        for cam, mask, uv in views:
            mu, inv = image_ellipses(
                cam, cw.reshape(-1, 3), Rw.reshape(-1, 3, 3), np.tile(r_on, (H, 1))
            )
            mu, inv = mu.reshape(H, E, 2), inv.reshape(H, E, 2, 2)
            total += covered(uv, mu, inv).sum(axis=1) * float(step) ** 2
            total -= w_background * background_area(mask, mu, inv).sum(axis=1)
        return total

    def cost(th):
        c = -score(th)
        return np.where(_new_folds(skel, grid, theta, th), np.inf, c) if no_fold else c

    base_score = float(score(theta[None])[0])
    best, best_cost = grid_search(skel, theta, grid, cost, -base_score, prior_px / sigma_prior**2)
    if best is theta:
        return 0.0, None
    return -base_score - best_cost, best


def search_limbs_silhouette(
    skel: Skeleton,
    balls: Metaballs,
    s: np.ndarray,
    theta0: np.ndarray,
    root: np.ndarray,
    cameras: list[Camera],
    masks: list,
    limbs: tuple | None = None,
    sigma_prior: float = 0.6,
    prior_px: float = 20.0,
    w_background: float = 1.0,
    min_gain_px: float = 200.0,
    rounds: int = 2,
    step: int = 2,
    allowed=None,
    unfold: bool = False,
    no_fold: bool = False,
    twist: bool = True,
) -> SilhouetteSearch:
    """Place each limb at the grid pose that best explains the foreground near it.

    Parameters
    ----------
    balls : Metaballs with the fitted radii (the search renders their visible ellipsoids)
    theta0 : (n,) start pose, radians; root : (3,) metres
    cameras, masks : the frame's cameras and their foreground masks (H, W) bool (None
        leaves a camera out)
    limbs : names of :data:`SILHOUETTE_LIMBS` (default all four)
    sigma_prior, prior_px : the prior towards the start, ``prior_px · Σ (Δθ/σ)²`` pixels
    w_background : weight of background pixels a limb covers, against 1 for the
        unexplained foreground it covers
    min_gain_px : a move must gain more than this many pixels (summed over cameras)
    rounds : moves per limb at most, greedy (the limb that gains most moves first)
    step : spacing of the foreground pixels sampled near a limb, pixels
    allowed : callable ``(theta, candidate) -> bool``, optional — a veto on a limb's move
        from the current pose ``theta`` (n,) to ``candidate`` (n,), e.g. when it would
        take the limb off the 3-D points that place it
    unfold : a folded knee or elbow (:func:`unfolded`) is also tried straightened
    no_fold : no move folds a knee or elbow the current pose has unfolded (beyond
        :data:`FOLDED_DEG`); the alternative :func:`folds` asks for
    twist : the arms' grids take the upper arm's twist (:data:`SILHOUETTE_LIMBS`);
        False searches the arms on :data:`core.fit_search.LIMBS`' grids

    Returns
    -------
    SilhouetteSearch
    """
    theta = np.asarray(theta0, float).copy()
    root = np.asarray(root, float).reshape(3)
    names = tuple(LIMBS) if limbs is None else tuple(limbs)
    grids = SILHOUETTE_LIMBS if twist else LIMBS
    moved: list[str] = []
    total = 0.0
    for _ in range(rounds * len(names)):
        best_gain, best_theta, best_name = min_gain_px, None, None
        for name in names:
            gain, th = _limb_gain(
                skel,
                balls,
                s,
                theta,
                root,
                unfolded(skel, grids[name], theta) if unfold else grids[name],
                cameras,
                masks,
                sigma_prior,
                prior_px,
                w_background,
                step,
                no_fold,
            )
            if gain > best_gain and (allowed is None or allowed(theta, th)):
                best_gain, best_theta, best_name = gain, th, name
        if best_theta is None:
            break
        theta, total = best_theta, total + best_gain
        if best_name not in moved:
            moved.append(best_name)
    return SilhouetteSearch(theta, moved, total)
