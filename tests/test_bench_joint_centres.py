"""bench.joint_centres' functional joint centre on synthetic segments moving about a
known joint."""

import numpy as np
from scipy.spatial.transform import Rotation

from bench.joint_centres import functional_centre, rigid_motion, segment_points


def _two_segments(rng, centre, relative):
    """Points of a proximal (above the centre) and a distal (below) segment, and per
    frame where they are seen: the proximal one moves freely, the distal one follows it
    turned by ``relative(k)`` about ``centre``; each frame sees a random subset."""
    a = centre + rng.normal(0, 0.04, (40, 3)) + [0, 0, 0.2]
    b = centre + rng.normal(0, 0.04, (30, 3)) - [0, 0, 0.2]
    fa, fb = [], []
    for k in range(12):
        r = Rotation.from_rotvec(rng.normal(0, 0.3, 3)).as_matrix()
        t = rng.normal(0, 0.1, 3)
        rel = relative(k)
        ia = np.sort(rng.choice(len(a), 25, replace=False))
        ib = np.sort(rng.choice(len(b), 20, replace=False))
        fa.append((ia, a[ia] @ r.T + t))
        fb.append((ib, ((b[ib] - centre) @ rel.T + centre) @ r.T + t))
    return a, b, fa, fb


def test_a_ball_joint_is_found_exactly():
    rng = np.random.default_rng(3)
    c = np.array([0.2, -0.1, 0.9])
    a, b, fa, fb = _two_segments(
        rng, c, lambda k: Rotation.from_rotvec(rng.normal(0, 0.5, 3)).as_matrix()
    )
    centre, normal = functional_centre(a, b, fa, fb)
    assert np.linalg.norm(centre - c) < 1e-9
    assert np.linalg.eigvalsh(normal)[0] > 1e-3  # every direction determined


def test_a_hinge_leaves_its_axis_undetermined():
    rng = np.random.default_rng(4)
    c = np.array([0.0, 0.3, 0.5])
    axis = np.array([1.0, 0.2, 0.0]) / np.hypot(1.0, 0.2)
    a, b, fa, fb = _two_segments(
        rng, c, lambda k: Rotation.from_rotvec(axis * 0.15 * k).as_matrix()
    )
    centre, normal = functional_centre(a, b, fa, fb)
    w, v = np.linalg.eigh(normal)
    assert w[0] < 1e-9 * w[1]
    assert abs(v[:, 0] @ axis) > 1 - 1e-9  # the weak direction is the hinge's axis
    off = centre - c
    assert np.linalg.norm(off - axis * (axis @ off)) < 1e-9  # on the axis


def test_rigid_motion_and_labels():
    rng = np.random.default_rng(5)
    p = rng.normal(0, 1, (10, 3))
    r = Rotation.from_rotvec([0.1, 0.2, -0.3]).as_matrix()
    got_r, got_t, rms = rigid_motion(p, p @ r.T + [1, 2, 3])
    assert np.allclose(got_r, r) and np.allclose(got_t, [1, 2, 3]) and rms < 1e-12
    segs = {
        "thigh": (np.array([0, 0, 1.0]), np.array([0, 0, 0.5])),
        "shin": (np.array([0, 0, 0.5]), np.array([0, 0, 0.0])),
    }
    pts = np.array([[0.05, 0, 0.75], [0.05, 0, 0.25], [0.05, 0, 0.51], [0.5, 0, 0.75]])
    got = segment_points(pts, segs)
    assert got["thigh"].tolist() == [0] and got["shin"].tolist() == [1]  # ends, far: none
