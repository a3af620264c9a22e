"""bench.seeding's limb counts on hand-placed points."""

import numpy as np

from bench.seeding import LIMBS, limb_counts


def test_points_are_counted_on_the_limb_they_lie_along():
    names = [j for js in LIMBS.values() for j in js]
    joints = np.zeros((len(names), 3))
    for k, limb in enumerate(LIMBS.values()):  # four parallel limbs 1 m apart, hanging
        for i, j in enumerate(limb):
            joints[names.index(j)] = [float(k), 0.0, 1.0 - 0.3 * i]
    arm = LIMBS["r_arm"]
    x = joints[names.index(arm[0])][0]
    pts = np.array(
        [
            [x + 0.05, 0.0, 0.9],  # beside the upper arm
            [x, 0.05, 0.5],  # beside the forearm
            [x, 0.0, 0.32],  # beyond the wrist: the hand
            [x, 0.0, 0.1],  # beyond the hand
            [x + 0.5, 0.0, 0.9],
        ]
    )  # between two limbs
    got = limb_counts(pts, joints, names)
    assert got["r_arm"] == 3
    assert sum(got.values()) == 3
