"""Free space in front of observed points: probes along the lines of sight, their cost,
and the explain cost of a limb placed in front of its own points."""

import numpy as np
import pytest

from core import metaball_surface as mbs
from core import metaballs as mb
from core import skeleton as sk
from core.fit_search import explain_cost, explain_distance, search_limbs
from core.free_space import occlusion_cost, probes
from tests.core._bodyscene import model_points


def test_probes_lie_on_the_lines_of_sight_of_the_cameras_that_saw_the_point():
    x = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0]])
    centres = np.array([[0.0, -5.0, 1.0], [5.0, 0.0, 1.0]])
    views = np.array([[True, False], [True, True]])
    p = probes(x, views, centres, depths=(0.03, 0.06))
    assert p.xyz.shape == (2, 4, 3) and p.valid.tolist() == [[1, 1, 0, 0], [1, 1, 1, 1]]
    assert np.allclose(p.xyz[0, :2], [[0, -0.03, 1], [0, -0.06, 1]])
    u = (centres[1] - x[1]) / np.linalg.norm(centres[1] - x[1])
    assert np.allclose(p.xyz[1, 3], x[1] + 0.06 * u)
    with pytest.raises(ValueError, match="cameras"):
        probes(x, views, centres[:1])


def test_occlusion_cost_counts_the_deepest_valid_probe_beyond_the_margin():
    d = np.array([[0.005, 0.02], [0.2, -0.1], [0.3, 0.3]])  # (N=3, K=2) metres, + inside
    valid = np.array([[True, True], [True, True], [False, False]])
    c = occlusion_cost(d, valid, margin=0.01, tau=0.05, sigma=0.01)
    assert np.allclose(c, [1.0, 25.0, 0.0])  # (0.02-0.01)²/σ²; capped at (τ/σ)²; unseen
    batched = occlusion_cost(np.stack([d, 0 * d]), valid)  # (H, N, K) -> (H, N)
    assert batched.shape == (2, 3) and np.allclose(batched[1], 0)


@pytest.fixture
def seen_arm(rng):
    """A body with the right arm bent, its surface points that one of two cameras on
    the body's right sees (a free line of sight), and the cameras' centres."""
    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    balls = mb.make_metaballs(skel, "simplified", s)
    root = np.array([0.0, 0.0, 1.0])
    true = np.zeros(skel.n_dof)
    true[skel.dof_index("r_shoulder_y")] = 0.5
    true[skel.dof_index("r_elbow_x")] = -0.6
    xyz, _ = model_points(skel, balls, true, root, s, rng, per_bone=80)
    pose = sk.forward(skel, true[None], root[None], s)
    Rw, cw = mb.world_frames(skel, pose, balls, s)
    x, ok = mbs.project_to_surface(xyz, Rw[0], cw[0], balls.radii)
    x = x[ok]
    j = sk.joint_positions(skel, true, root, s)
    mid = 0.5 * (j[skel.joint_index("r_elbow")] + j[skel.joint_index("r_wrist")])
    cams = np.array([[mid[0] + 4.0, mid[1] - 3.0, 1.2], [mid[0] + 4.5, mid[1] + 2.0, 1.3]])
    views = np.zeros((len(x), len(cams)), bool)
    for c, centre in enumerate(cams):
        u = centre - x
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        free = np.ones(len(x), bool)
        for t in np.linspace(0.005, 0.5, 40):
            free &= explain_distance(x + t * u, skel, balls, s, balls.radii, true, root) < 0
        views[:, c] = free
    seen = views.any(axis=1)
    return skel, s, balls, root, true, x[seen], views[seen], cams


def test_a_limb_in_front_of_its_own_points_pays_for_the_body_in_their_line_of_sight(seen_arm):
    skel, s, balls, root, true, x, views, cams = seen_arm
    pr = probes(x, views, cams)
    # the arm swung forward, between the cameras and points it no longer explains
    wrong = true.copy()
    wrong[skel.dof_index("r_shoulder_x")] -= np.radians(10)
    roots = np.stack([root, root])
    plain = explain_cost(x, skel, balls, s, balls.radii, np.stack([true, wrong]), roots)
    seen = explain_cost(x, skel, balls, s, balls.radii, np.stack([true, wrong]), roots, probes=pr)
    assert plain[0] < 1e-9 and seen[0] < 1e-9  # the truth: nothing in front of its points
    assert seen[1] - plain[1] > 100  # the wrong pose occludes many of them
    # the search with the lines of sight still returns to the truth
    res = search_limbs(x, skel, balls, s, balls.radii, wrong, root, probes=pr)
    j = sk.joint_positions(skel, res.theta, root, s)
    jt = sk.joint_positions(skel, true, root, s)
    w = skel.joint_index("r_wrist")
    assert res.moved == ["r_arm"] and np.linalg.norm(j[w] - jt[w]) < 0.03


def test_a_hidden_leg_that_swung_into_the_other_is_moved_out_of_its_points(rng):
    """The right leg has no points (hidden) and the prediction swung it into the left
    leg: the search, with the lines of sight, moves it out of the points it buries."""
    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    balls = mb.make_metaballs(skel, "simplified", s)
    root = np.array([0.0, 0.0, 1.0])
    true = np.zeros(skel.n_dof)
    true[skel.dof_index("l_hip_x")] = -0.3
    xyz, part = model_points(skel, balls, true, root, s, rng, per_bone=60)
    pose = sk.forward(skel, true[None], root[None], s)
    Rw, cw = mb.world_frames(skel, pose, balls, s)
    x, ok = mbs.project_to_surface(xyz, Rw[0], cw[0], balls.radii)
    leg = [skel.bone_index(b) for b in ("r_hip", "r_knee", "r_ankle")]
    x = x[ok & ~np.isin(part, leg)]
    centre = np.array([0.0, -5.0, 1.0])
    u = centre - x
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    seen = np.ones(len(x), bool)
    for t in np.linspace(0.005, 0.8, 40):
        seen &= explain_distance(x + t * u, skel, balls, s, balls.radii, true, root) < 0
    start = true.copy()
    start[skel.dof_index("r_hip_x")] -= 0.3
    start[skel.dof_index("r_hip_y")] -= 0.25  # across the body, into the left leg
    buried = explain_distance(x, skel, balls, s, balls.radii, start, root) > 0.01
    assert buried.sum() > 50
    res = search_limbs(
        x, skel, balls, s, balls.radii, start, root, probes=probes(x, seen[:, None], centre[None])
    )
    assert "r_leg" in res.moved
    after = explain_distance(x, skel, balls, s, balls.radii, res.theta, root)
    assert (after > 0.01).sum() < 5


def test_tracks_give_each_point_the_cameras_that_measured_it(tmp_path):
    from core.errors import InputError
    from core.fit_scene import observations_from_tracks

    xyz = np.zeros((2, 3, 3))
    xyz[1, 2] = np.nan  # trajectory 2 not measured in frame 1
    uv = np.ones((2, 3, 2, 2))
    uv[0, 1, 0] = np.nan  # camera 0 did not match trajectory 1 in frame 0
    np.savez(tmp_path / "tracks.npz", xyz=xyz, uv=uv)
    obs = observations_from_tracks(tmp_path / "tracks.npz", 2)
    assert obs[0].views.tolist() == [[True, True], [False, True], [True, True]]
    assert obs[1].views.shape == (2, 2) and obs[1].ids.tolist() == [0, 1]
    np.savez(tmp_path / "old.npz", xyz=xyz)  # no image points: no lines of sight
    assert observations_from_tracks(tmp_path / "old.npz", 2)[0].views is None
    with pytest.raises(InputError, match="old.npz"):
        observations_from_tracks(tmp_path / "old.npz", 3)
