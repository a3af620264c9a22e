"""The committed default scene loads without ../shared or bpy and its truth is consistent."""

from __future__ import annotations

import numpy as np

from core.landmarks import CLICK_JOINTS, JOINTS, METRIC_JOINTS
from core.scene import TRUTH_KEYS, load_scene
from tests.conftest import DEFAULT_SCENE


def test_default_scene_is_complete_and_small():
    scene = load_scene(DEFAULT_SCENE)
    assert scene.cameras == ["cam01", "cam02", "cam03"] and scene.n_frames == 50
    assert scene.size == (512, 384) and scene.fps == 25.0
    assert set(TRUTH_KEYS) <= set(scene.truth)
    assert len(scene.wand_frames()["cam01"]) >= 150 and scene.wand_length() == 0.5
    assert set(scene.clicks()["joints"]) == set(CLICK_JOINTS)
    total = sum(p.stat().st_size for p in DEFAULT_SCENE.rglob("*") if p.is_file())
    assert total <= 20e6
    assert "mocap.cs.cmu.edu" in (DEFAULT_SCENE.parent / "ATTRIBUTION").read_text()


def test_default_scene_truth_agrees_with_images():
    scene = load_scene(DEFAULT_SCENE)
    cams = scene.calibration()
    masks = scene.truth_masks()
    xyz = scene.truth["joints_xyz"][:, [JOINTS.index(j) for j in METRIC_JOINTS]]
    clicks = scene.clicks()["joints"]
    for c, cam in enumerate(cams):
        for f in (0, 25, 49):
            uv = np.round(cam.project(xyz[f])).astype(int)
            assert masks[c, f][uv[:, 1], uv[:, 0]].all()
        grey = scene.image(c, 0).astype(int)
        assert np.abs(grey[masks[c, 0]] - grey[0, 0]).mean() > 20  # textured person
        # Clicks are the truth joints projected (no click noise in the default scene).
        uv = np.array([clicks[j][cam.name] for j in METRIC_JOINTS])
        np.testing.assert_allclose(uv, cam.project(xyz[0]), atol=1e-3)
