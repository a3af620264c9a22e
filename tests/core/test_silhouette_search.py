"""Limb search against foreground masks (core/silhouette_search.py)."""

import numpy as np
import pytest

from core import metaballs as mb
from core import skeleton as sk
from core.contour_obs import body_ellipsoids
from core.model_render import render_parts
from core.silhouette_search import (
    FOLDED_DEG,
    SILHOUETTE_LIMBS,
    folds,
    image_ellipses,
    mask_grid,
    recentre_root,
    search_limbs_silhouette,
    silhouette_disagreement,
    silhouette_iou,
    unfolded,
)
from tests.core._bodyscene import cameras, look_at


@pytest.fixture
def body():
    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    return skel, s, mb.make_metaballs(skel, "simplified", s)


def _masks(skel, balls, theta, root, s, cams):
    """Exact ray-cast silhouettes (core.model_render) of the model in every camera."""
    c, a, r, p = body_ellipsoids(skel, theta, root, s, balls)
    return [render_parts(cam, c, a, r, p).mask for cam in cams]


def test_image_ellipse_matches_the_ray_cast_outline(rng):
    cam = look_at("c", (0.4, -3.0, 1.3), target=(0.0, 0.0, 1.0))
    for _ in range(5):
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        centre = rng.normal([0, 0, 1.0], 0.3)
        radii = rng.uniform(0.04, 0.15, 3)
        mask = render_parts(cam, centre[None], q[None], radii[None], np.zeros(1, int)).mask
        mu, inv = image_ellipses(cam, centre[None], q[None], radii[None])
        v, u = np.mgrid[0 : mask.shape[0], 0 : mask.shape[1]]
        d = np.stack([u - mu[0, 0], v - mu[0, 1]], axis=-1)
        ours = np.einsum("hwi,ij,hwj->hw", d, inv[0], d) <= 1.0
        iou = (ours & mask).sum() / (ours | mask).sum()
        assert iou > 0.95, iou


def test_an_arm_out_of_place_is_put_back_and_an_arm_without_evidence_stays(body):
    skel, s, balls = body
    cams = cameras()
    root = np.array([0.0, 0.0, 1.0])
    true = np.zeros(skel.n_dof)
    true[skel.dof_index("r_shoulder_x")] = -1.0  # right arm raised forward
    true[skel.dof_index("r_elbow_x")] = 0.6
    masks = _masks(skel, balls, true, root, s, cams)
    start = true.copy()
    start[skel.dof_index("r_shoulder_x")] = 0.0  # the fit lost it: hanging down
    start[skel.dof_index("r_elbow_x")] = 0.0
    res = search_limbs_silhouette(skel, balls, s, start, root, cams, masks)
    wrist = skel.joint_index("r_wrist")
    before = np.linalg.norm(
        sk.joint_positions(skel, start, root, s)[wrist]
        - sk.joint_positions(skel, true, root, s)[wrist]
    )
    after = np.linalg.norm(
        sk.joint_positions(skel, res.theta, root, s)[wrist]
        - sk.joint_positions(skel, true, root, s)[wrist]
    )
    assert before > 0.3 and after < 0.08, (before, after)
    assert res.moved == ["r_arm"]
    grids = [mask_grid(m) for m in masks]
    assert silhouette_disagreement(
        skel, balls, res.theta, root, s, cams, grids
    ) < 0.3 * silhouette_disagreement(skel, balls, start, root, s, cams, grids)
    # at the true pose nothing is left unexplained: no limb moves
    again = search_limbs_silhouette(skel, balls, s, true, root, cams, masks)
    assert again.moved == [] and np.array_equal(again.theta, true)


def test_a_vetoed_move_is_not_made(body):
    """``allowed`` vetoes a limb's move (the 3-D points that place the limb disagree):
    the arm the silhouettes would raise stays down, and the veto sees the candidate."""
    skel, s, balls = body
    cams = cameras()
    root = np.array([0.0, 0.0, 1.0])
    true = np.zeros(skel.n_dof)
    true[skel.dof_index("r_shoulder_x")] = -1.0
    masks = _masks(skel, balls, true, root, s, cams)
    start = np.zeros(skel.n_dof)
    seen = []

    def veto(theta, cand):
        seen.append(cand[skel.dof_index("r_shoulder_x")] - theta[skel.dof_index("r_shoulder_x")])
        return False

    res = search_limbs_silhouette(skel, balls, s, start, root, cams, masks, allowed=veto)
    assert res.moved == [] and np.array_equal(res.theta, start)
    assert min(seen) < -0.5  # the raise was offered, and refused
    assert search_limbs_silhouette(
        skel, balls, s, start, root, cams, masks, allowed=lambda th, c: True
    ).moved == ["r_arm"]


def test_a_camera_without_a_mask_is_left_out(body):
    skel, s, balls = body
    cams = cameras()
    root = np.array([0.0, 0.0, 1.0])
    theta = np.zeros(skel.n_dof)
    res = search_limbs_silhouette(skel, balls, s, theta, root, cams, [None] * len(cams))
    assert res.moved == [] and res.gain_px == 0.0
    empty = mask_grid(np.zeros((384, 512), bool))
    assert len(empty.uv) == 0
    assert silhouette_disagreement(skel, balls, theta, root, s, cams, [empty] * 3) == 0.0


def test_silhouette_iou_is_high_at_the_pose_and_falls_as_the_body_leaves(body):
    skel, s, balls = body
    cams = cameras()
    root = np.array([0.0, 0.0, 1.0])
    theta = np.zeros(skel.n_dof)
    theta[skel.dof_index("l_shoulder_x")] = -0.7
    grids = [mask_grid(m) for m in _masks(skel, balls, theta, root, s, cams)]
    at = silhouette_iou(skel, balls, theta, root, s, cams, grids)
    near = silhouette_iou(skel, balls, theta, root + [0.1, 0.0, 0.0], s, cams, grids)
    far = silhouette_iou(skel, balls, theta, root + [0.0, 0.0, -25.0], s, cams, grids)
    assert np.all(at > 0.95) and np.all(near < 0.8) and np.all(far == 0.0), (at, near, far)
    grids[1] = mask_grid(np.zeros((384, 512), bool))
    assert np.isnan(silhouette_iou(skel, balls, theta, root, s, cams, grids)[1])


def test_recentre_root_finds_a_body_that_moved_beyond_the_contours_reach(body):
    skel, s, balls = body
    cams = cameras()
    theta = np.zeros(skel.n_dof)
    true_root = np.array([0.3, 0.15, 1.05])
    grids = [mask_grid(m) for m in _masks(skel, balls, theta, true_root, s, cams)]
    for start in (np.array([0.0, 0.0, 1.0]), np.array([-0.4, 0.3, 1.0])):
        got = recentre_root(skel, balls, theta, start, s, cams, grids)
        assert np.linalg.norm(got - true_root) < 0.03, (start, got)
    # one camera alone cannot place it in depth: unchanged
    one = [grids[0]] + [mask_grid(np.zeros((384, 512), bool))] * 2
    start = np.array([0.0, 0.0, 1.0])
    assert np.array_equal(recentre_root(skel, balls, theta, start, s, cams, one), start)


def test_a_bent_arm_twisted_out_of_place_is_turned_back(body):
    """The forearm of a bent arm swings about the upper arm with its twist; the
    silhouette search has the twist in the arm's grid and puts the wrist back, and
    with ``twist=False`` leaves the twist where it was."""
    skel, s, balls = body
    cams = cameras()
    root = np.array([0.0, 0.0, 1.0])
    true = np.zeros(skel.n_dof)
    true[skel.dof_index("l_shoulder_x")] = -0.3
    true[skel.dof_index("l_elbow_x")] = -1.3  # bent (flexion is negative)
    true[skel.dof_index("l_shoulder_z")] = 0.9
    masks = _masks(skel, balls, true, root, s, cams)
    start = true.copy()
    start[skel.dof_index("l_shoulder_z")] = 0.0
    res = search_limbs_silhouette(skel, balls, s, start, root, cams, masks)
    wrist = skel.joint_index("l_wrist")
    want = sk.joint_positions(skel, true, root, s)[wrist]
    before = np.linalg.norm(sk.joint_positions(skel, start, root, s)[wrist] - want)
    after = np.linalg.norm(sk.joint_positions(skel, res.theta, root, s)[wrist] - want)
    assert before > 0.15 and after < 0.05, (before, after)
    assert res.moved == ["l_arm"]
    # without the twist in the grid (frames with points) the twist is left to the fit
    plain = search_limbs_silhouette(skel, balls, s, start, root, cams, masks, twist=False)
    twist = skel.dof_index("l_shoulder_z")
    assert plain.theta[twist] == start[twist]


def test_a_shin_folded_onto_its_thigh_is_unfolded_only_with_the_absolute_flexions(body):
    """A fit that folded the shin onto the thigh (knee 2.8 rad) hides it inside the
    thigh's outline, where it costs nothing; the true leg is straight.  The offsets
    (±60°, two rounds) cannot reach it; ``unfold`` tries the folded knee straight
    too, and looks as far as the straightened leg reaches."""
    skel, s, balls = body
    cams = [look_at("front", (0.0, -4.0, 1.0)), look_at("side", (4.0, 0.0, 1.0))]
    root = np.array([0.0, 0.0, 1.0])
    true = np.zeros(skel.n_dof)
    true[skel.dof_index("r_hip_x")] = -0.5  # the right thigh forward, its shin straight
    masks = _masks(skel, balls, true, root, s, cams)
    start = true.copy()
    start[skel.dof_index("r_knee_x")] = 2.8  # folded: the heel at the buttock
    ankle = skel.joint_index("r_ankle")
    x_true = sk.joint_positions(skel, true, root, s)[ankle]

    def off(theta):
        return np.linalg.norm(sk.joint_positions(skel, theta, root, s)[ankle] - x_true)

    plain = search_limbs_silhouette(skel, balls, s, start, root, cams, masks)
    found = search_limbs_silhouette(skel, balls, s, start, root, cams, masks, unfold=True)
    assert off(start) > 0.5
    assert off(plain.theta) > 0.25, off(plain.theta)
    assert off(found.theta) < 0.05, off(found.theta)
    # a knee bent but not folded keeps the plain grid: the search is the default one
    bent = start.copy()
    bent[skel.dof_index("r_knee_x")] = 1.5
    assert unfolded(skel, SILHOUETTE_LIMBS["r_leg"], bent) == SILHOUETTE_LIMBS["r_leg"]
    assert unfolded(skel, SILHOUETTE_LIMBS["r_leg"], start) != SILHOUETTE_LIMBS["r_leg"]


def test_a_fold_the_search_makes_is_flagged_and_left_out_with_no_fold(body):
    """The true shin folded onto its thigh (knee 2.6 rad), the start's knee nearly
    straight: the search folds it — a move :func:`folds` flags, so that the sequence
    fit weighs it against the search with ``no_fold``, which bends the knee no further
    than :data:`FOLDED_DEG`.  A start already folded is not held by ``no_fold``."""
    skel, s, balls = body
    cams = [look_at("front", (0.0, -4.0, 1.0)), look_at("side", (4.0, 0.0, 1.0))]
    root = np.array([0.0, 0.0, 1.0])
    knee = skel.dof_index("r_knee_x")
    true = np.zeros(skel.n_dof)
    true[skel.dof_index("r_hip_x")] = -0.3
    true[knee] = 2.6
    masks = _masks(skel, balls, true, root, s, cams)
    start = true.copy()
    start[knee] = 0.3
    limit = np.radians(FOLDED_DEG)

    found = search_limbs_silhouette(skel, balls, s, start, root, cams, masks)
    held = search_limbs_silhouette(skel, balls, s, start, root, cams, masks, no_fold=True)
    assert found.theta[knee] > limit, np.degrees(found.theta[knee])
    assert folds(skel, start, found.theta)
    assert "r_leg" in held.moved and held.theta[knee] <= limit, np.degrees(held.theta[knee])
    assert not folds(skel, start, held.theta)
    # folding further a knee that is folded already is no new fold
    assert not folds(skel, found.theta, true)
    again = search_limbs_silhouette(skel, balls, s, true, root, cams, masks, no_fold=True)
    assert again.theta[knee] > limit
