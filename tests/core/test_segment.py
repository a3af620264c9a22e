"""Segmentation of 3-D points to body parts at a posture."""

import numpy as np

from core import metaballs as mb
from core import skeleton as sk
from core.segment import carry_labels, no_labels, segment_points
from tests.core._bodyscene import model_points


def test_points_on_each_part_are_assigned_to_it_and_far_points_to_none(rng):
    skel = sk.make_skeleton()
    balls = mb.make_metaballs(skel)
    theta = rng.normal(0, 0.15, skel.n_dof)
    for side, sign in (("l", 1), ("r", -1)):  # arms away from the trunk
        theta[skel.dof_index(f"{side}_shoulder_y")] = sign * 0.5
    root, s = np.array([0.0, 0.0, 1.0]), np.ones(skel.n_groups)
    xyz, part = model_points(skel, balls, theta, root, s, rng, per_bone=30)
    # observable points lie on the body's outer surface, not inside another part
    pose = sk.forward(skel, theta[None], root[None], s)
    Rw, cw = mb.world_frames(skel, pose, balls, s)
    outer = mb.field(xyz, Rw[0], cw[0], balls.radii)[0] < 0.7
    xyz, part = xyz[outer], part[outer]
    assert len(part) > 100
    far = np.array([[3.0, 0.0, 1.0], [0.0, 2.0, 0.5]])
    got, dist = segment_points(np.concatenate([xyz, far]), skel, balls, theta, root, s)
    assert np.all(got[-2:] == -1)
    # away from the joints (where neighbouring parts overlap) the label is the truth
    assert np.mean(got[:-2] == part) > 0.85
    assert np.all(np.abs(dist[:-2][got[:-2] == part]) < 0.05)


def test_tracked_points_keep_their_first_label():
    known = no_labels()
    part, known = carry_labels(np.array([3, 4, -1]), np.array([10, 11, 12]), known)
    assert part.tolist() == [3, 4, -1]
    part, known = carry_labels(np.array([5, 5, 7]), np.array([11, 12, 10]), known)
    assert part.tolist() == [4, 5, 3]  # 11 and 10 keep theirs; 12 is new
    assert dict(zip(known[0].tolist(), known[1].tolist(), strict=True)) == {10: 3, 11: 4, 12: 5}


def test_margin_drops_exactly_the_points_ambiguous_between_non_adjacent_parts(rng):
    from core.segment import surface_distance

    skel = sk.make_skeleton()
    balls = mb.make_metaballs(skel)
    theta, root, s = np.zeros(skel.n_dof), np.array([0.0, 0.0, 1.0]), np.ones(skel.n_groups)
    pose = sk.forward(skel, theta[None], root[None], s)
    Rw, cw = mb.world_frames(skel, pose, balls, s)
    # points around the hanging hands and the thighs beside them
    near = [skel.bone_index(b) for b in ("l_wrist", "l_hip", "r_wrist", "r_hip")]
    c = cw[0, np.isin(balls.bone, near)]
    xyz = c[rng.integers(0, len(c), 400)] + rng.normal(0, 0.06, (400, 3))
    plain, d = segment_points(xyz, skel, balls, theta, root, s)
    got, _ = segment_points(xyz, skel, balls, theta, root, s, margin=0.02)
    kept = got >= 0
    assert np.all(got[kept] == plain[kept])  # the margin only removes points
    dropped = (plain >= 0) & ~kept
    assert dropped.sum() > 10 and kept.sum() > 50
    dist = surface_distance(xyz, Rw[0], cw[0], balls.visible)
    for i in np.nonzero(plain >= 0)[0]:
        b = plain[i]
        adjacent = {b, skel.bone_parent[b], *np.nonzero(skel.bone_parent == b)[0]}
        other = ~np.isin(balls.bone, list(adjacent))
        assert (dist[i, other].min() - d[i] < 0.02) == dropped[i]
