"""The limb search of contour tracking re-poses a limb left behind by fast motion."""

import numpy as np

import core.contour_track as ct
from core.contour_search import LIMBS, SearchSettings, search_limbs
from core.skeleton import joint_positions
from tests.core.test_contour_divergence import rig  # noqa: F401  (fixture)


def test_search_brings_a_lost_forearm_back(rig):  # noqa: F811
    skel, balls, s, cams, theta, root, contours = rig
    fields = ct.frame_fields(cams, contours)
    start = theta.copy()
    start[skel.dof_index("l_shoulder_x")] += 0.8  # the arm swung far from its silhouette
    start[skel.dof_index("l_elbow_x")] -= 0.6
    res = search_limbs(
        skel, start, root, s, balls, cams, contours, fields, cfg=SearchSettings(samples=48, seed=1)
    )
    assert "l_arm" in res.moved
    wrist = skel.joint_names.index("l_wrist")

    def err(th):
        return np.linalg.norm(
            joint_positions(skel, th, root, s)[wrist] - joint_positions(skel, theta, root, s)[wrist]
        )

    assert err(res.theta) < 0.5 * err(start)
    # only the searched DOFs of moved limbs change
    searched = [skel.dof_index(d) for name in res.moved for d in LIMBS[name][1]]
    other = np.setdiff1d(np.arange(skel.n_dof), searched)
    np.testing.assert_array_equal(res.theta[other], start[other])


def test_search_keeps_a_pose_that_explains_the_silhouettes(rig):  # noqa: F811
    skel, balls, s, cams, theta, root, contours = rig
    fields = ct.frame_fields(cams, contours)
    res = search_limbs(skel, theta, root, s, balls, cams, contours, fields)
    assert res.moved == [] or max(res.gain_px.values()) < 3.0
    np.testing.assert_allclose(res.root, root)
