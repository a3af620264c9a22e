"""The camera-selection switch of contour tracking: visibility only vs motion-ranked."""

import numpy as np

import core.contour_track as ct
from core.contour_obs import body_ellipsoids
from core.contours import occluding_contours
from core.metaballs import make_metaballs
from core.model_render import render_parts
from core.skeleton import make_skeleton
from tests.core.test_contour_obs import _look_at


def test_visibility_only_selection_uses_every_visible_camera(monkeypatch):
    skel = make_skeleton()
    balls = make_metaballs(skel)
    s = np.ones(skel.n_groups)
    target = np.array([0.0, 0.0, 1.0])
    cams = [
        _look_at(target + d, target)
        for d in (np.array([0.0, -4.0, 0.0]), np.array([4.0, 0.0, 0.0]))
    ]
    theta = np.zeros(skel.n_dof)
    theta[skel.dof_index("l_shoulder_x")] = 0.4
    root = np.array([0.0, 0.0, 1.0])
    c, a, r, p = body_ellipsoids(skel, theta, root, s, balls)
    renders = [render_parts(cam, c, a, r, p, len(skel.bone_names)) for cam in cams]
    contours = [occluding_contours(x.mask, spacing=1.5) for x in renders]
    rates = []
    real = ct.contour_observations

    def spy(*args, **kw):
        rates.append(kw.get("theta_rate"))
        return real(*args, **kw)

    monkeypatch.setattr(ct, "contour_observations", spy)
    uses = {}
    for observability in (True, False):
        cfg = ct.ContourTrackSettings(iterations=1, observability=observability)
        ekf = ct.start_filter(skel, theta, root, cfg)
        ekf.x[skel.n_dof + 3 + skel.dof_index("l_shoulder_x")] = 0.05  # a moving arm
        out = ct.update_with_contours(ekf, skel, s, balls, cams, contours, cfg)
        uses[observability] = out.use
    assert rates[0] is not None and rates[1] is None
    vis = np.stack([x.visibility_index for x in renders], axis=1)
    np.testing.assert_array_equal(uses[False], np.nan_to_num(vis) >= 0.2)
