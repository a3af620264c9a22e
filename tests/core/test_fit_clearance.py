"""A hidden arm the fill rules put inside the trunk is moved out of it (core.fit_clearance)."""

import numpy as np

from core import metaballs as mb
from core import skeleton as sk
from core.fit_clearance import ARM_BONES, clear_trunk, trunk_depth
from core.metaball_surface import deflate

#: a right arm swung across the belly, its forearm deep in the trunk
INSIDE = {"r_shoulder_x": 0.24, "r_shoulder_y": 0.22, "r_shoulder_z": 1.24, "r_elbow_x": -1.36}
#: the same arm raised sideways, well clear of the trunk
CLEAR = {"r_shoulder_y": 1.2, "r_elbow_x": -0.3, "l_shoulder_y": 1.2}


def _body():
    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    balls = deflate(skel, mb.make_metaballs(skel, "simplified", s), s)
    return skel, s, balls


def _pose(skel, angles):
    th = np.zeros(skel.n_dof)
    for k, v in angles.items():
        th[skel.dof_index(k)] = v
    return th


def _arm_dofs(skel, side):
    bones = [skel.bone_names.index(f"{side}_{b}") for b in ARM_BONES]
    return np.isin(skel.dof_bones(), bones)


def test_a_hidden_arm_inside_the_trunk_leaves_it_by_a_small_turn():
    skel, s, balls = _body()
    clear = [skel.bone_names.index(b) for b in ("r_elbow", "r_wrist")]
    root = np.tile([0.0, 0.0, 1.0], (4, 1))
    # frame 0: hidden and inside; 1: observed, clear; 2: hidden and clear; 3: hidden and
    # inside, but the frame diverged
    theta = np.stack(
        [_pose(skel, INSIDE), _pose(skel, CLEAR), _pose(skel, CLEAR), _pose(skel, INSIDE)]
    )
    right = _arm_dofs(skel, "r")
    unobs = np.zeros_like(theta, bool)
    unobs[[0, 2, 3]] = right
    diverged = np.array([False, False, False, True])
    before = trunk_depth(skel, balls, s, theta[0], root[0], clear).max()
    assert before > 1.0  # the forearm is deep inside

    out, rep = clear_trunk(skel, balls, s, theta, root, unobs, diverged, level=0.3)

    assert rep.frames == [(0, "r")]
    assert rep.before[0] == before
    after = trunk_depth(skel, balls, s, out[0], root[0], clear).max()
    assert after <= 0.31 and rep.after[0] == after
    # only the hidden arm's angles moved, and by a turn, not a new pose
    assert np.array_equal(out[0, ~right], theta[0, ~right])
    assert 0.05 < np.abs(out[0] - theta[0]).max() < 1.0
    # within the joint limits
    assert np.all(out[0] >= skel.dof_lo - 1e-9) and np.all(out[0] <= skel.dof_hi + 1e-9)
    # the observed arm and the diverged frame are left as they were; the hidden clear
    # arm next to the moved one takes a share of its correction (the spread) and stays
    # clear
    assert np.array_equal(out[1], theta[1]) and np.array_equal(out[3], theta[3])
    assert np.abs(out[2] - theta[2]).max() < np.abs(out[0] - theta[0]).max()
    assert trunk_depth(skel, balls, s, out[2], root[2], clear).max() <= 0.3
    # frame by frame, without the spread, the clear arm is not touched at all
    alone, _ = clear_trunk(skel, balls, s, theta, root, unobs, diverged, spread=0.0)
    assert np.array_equal(alone[1:], theta[1:])
    assert np.allclose(alone[0], out[0], atol=0.05)


def test_an_arm_the_data_put_as_deep_in_the_trunk_sets_how_deep_it_may_go():
    """Where the observations (or the clicks) put the arm as deep in this body's trunk,
    the same depth is not pulled out in a hidden frame; deeper still is, to that depth."""
    skel, s, balls = _body()
    clear = [skel.bone_names.index(b) for b in ("r_elbow", "r_wrist")]
    root = np.tile([0.0, 0.0, 1.0], (3, 1))
    shallower = dict(INSIDE, r_elbow_x=-0.8)  # the forearm less far in
    theta = np.stack([_pose(skel, shallower), _pose(skel, shallower), _pose(skel, INSIDE)])
    unobs = np.zeros_like(theta, bool)
    unobs[1:] = _arm_dofs(skel, "r")
    depth = [trunk_depth(skel, balls, s, theta[f], root[f], clear).max() for f in range(3)]
    assert depth[2] > depth[0] + 0.1
    kw = dict(level=0.3, spread=0.0)
    out, rep = clear_trunk(skel, balls, s, theta, root, unobs, np.zeros(3, bool), **kw)
    assert rep.frames == [(2, "r")] and np.array_equal(out[:2], theta[:2])
    assert rep.after[0] <= depth[0] + 0.01
    # the clicked frame counts as known too
    unobs[0] = unobs[1]
    out, rep = clear_trunk(
        skel, balls, s, theta, root, unobs, np.zeros(3, bool), ref_frames=(0,), **kw
    )
    assert rep.frames == [(2, "r")] and np.array_equal(out[:2], theta[:2])


def test_an_arm_whose_shoulder_the_observations_placed_is_never_moved():
    """Only the forearm and hand hidden: the shoulder's angles come from the upper arm's
    own observations, so the arm is where the data put it."""
    skel, s, balls = _body()
    theta = _pose(skel, INSIDE)[None]
    root = np.array([[0.0, 0.0, 1.0]])
    unobs = np.zeros_like(theta, bool)
    for b in ("r_elbow", "r_wrist"):
        unobs[0, skel.dof_bones() == skel.bone_names.index(b)] = True
    out, rep = clear_trunk(skel, balls, s, theta, root, unobs, np.zeros(1, bool))
    assert rep.frames == [] and np.array_equal(out, theta)


def test_a_hidden_arm_outside_the_silhouettes_is_brought_back_inside_them():
    """The rules swung the arm out sideways where every camera's foreground shows only
    the body with the arm down: held inside the foregrounds it comes back down."""
    from core.contour_obs import silhouette_field
    from tests.core._contourscene import _cams, _silhouettes

    skel, s, balls = _body()
    cams = _cams()
    root = np.array([[0.0, 0.0, 1.0]])
    truth = _pose(skel, {"r_shoulder_y": 0.15, "r_elbow_x": -0.3})
    filled = _pose(skel, {"r_shoulder_y": 1.3, "r_elbow_x": -0.3})
    fields = [
        silhouette_field(c, cam.size)
        for c, cam in zip(_silhouettes(skel, balls, truth, root[0], s, cams), cams, strict=True)
    ]
    unobs = _arm_dofs(skel, "r")[None]
    wrist = skel.joint_names.index("r_wrist")

    def wrist_error(th):
        x = sk.joint_positions(skel, th, root[0], s)[wrist]
        return np.linalg.norm(x - sk.joint_positions(skel, truth, root[0], s)[wrist])

    out, rep = clear_trunk(
        skel, balls, s, filled[None], root, unobs, np.zeros(1, bool), views=[(cams, fields)]
    )
    assert rep.frames == [(0, "r")] and rep.px_before[0] > 20.0 and rep.px_after[0] < 2.0
    assert wrist_error(filled) > 0.3 and wrist_error(out[0]) < 0.1
    assert np.array_equal(out[0, ~unobs[0]], filled[~unobs[0]])
    # without the views only the trunk counts, and the arm out sideways is left alone
    same, rep = clear_trunk(skel, balls, s, filled[None], root, unobs, np.zeros(1, bool))
    assert rep.frames == [] and np.array_equal(same, filled[None])
