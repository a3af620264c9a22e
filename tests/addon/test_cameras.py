"""Blender cameras from a calibration and back (OpenCV K, R, t <-> lens, sensor, shift)."""

from __future__ import annotations

import numpy as np
import pytest

from addon import cameras as bc
from core.camera import Camera, rodrigues_to_matrix


def _random_cameras(rng, n=3):
    cams = []
    for i in range(n):
        W, H = [(512, 384), (640, 240), (320, 480)][i % 3]
        aspect = [1.0, 2.0, 0.8][i % 3]  # fx / fy: square, one interlaced field, tall
        fx = rng.uniform(400, 900)
        K = [
            [fx, 0, W / 2 + rng.uniform(-20, 20)],
            [0, fx / aspect, H / 2 + rng.uniform(-15, 15)],
            [0, 0, 1],
        ]
        R = rodrigues_to_matrix(rng.normal(size=3))
        t = rng.uniform(-1, 1, 3) + [0, 0, 5]
        cams.append(Camera(f"cam{i:02d}", (W, H), K, rng.normal(0, 0.01, 5), R, t))
    return cams


def test_intrinsics_round_trip_pure(rng):
    for cam in _random_cameras(rng, 6):
        p = bc.blender_intrinsics(cam.K, cam.size)
        H_mm = p["sensor_width"] * cam.size[1] / cam.size[0]
        K = bc.intrinsics_from_blender(
            p["lens"],
            p["sensor_width"],
            H_mm,
            p["sensor_fit"],
            p["shift_x"],
            p["shift_y"],
            cam.size,
            p["pixel_aspect_x"],
            p["pixel_aspect_y"],
        )
        np.testing.assert_allclose(K, cam.K, rtol=1e-12, atol=1e-9)
        assert min(p["pixel_aspect_x"], p["pixel_aspect_y"]) == 1.0
        assert p["pixel_aspect_y"] / p["pixel_aspect_x"] == pytest.approx(cam.aspect)


def test_extrinsics_round_trip_pure(rng):
    for cam in _random_cameras(rng, 4):
        M = bc.blender_matrix_world(cam.R, cam.t)
        # Blender camera looks down its -z: the world direction to the optical axis.
        np.testing.assert_allclose(-M[:3, 2], cam.R[2], atol=1e-12)
        R, t = bc.extrinsics_from_matrix_world(M)
        np.testing.assert_allclose(R, cam.R, atol=1e-12)
        np.testing.assert_allclose(t, cam.t, atol=1e-12)


@pytest.mark.blender
def test_blender_cameras_round_trip_and_project(empty_blend, rng):
    bpy = empty_blend
    from bpy_extras.object_utils import world_to_camera_view
    from mathutils import Vector

    cams = _random_cameras(rng, 3)
    objs = bc.create_cameras(cams, scene=bpy.context.scene)
    assert [o.name for o in objs] == [c.name for c in cams]
    for cam, obj in zip(cams, objs, strict=True):
        back = bc.camera_from_object(obj)
        # Blender stores floats in single precision: 1e-6 relative / metres.
        np.testing.assert_allclose(back.K, cam.K, rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(back.R, cam.R, atol=1e-6)
        np.testing.assert_allclose(back.t, cam.t, atol=1e-6)
        np.testing.assert_allclose(back.dist, cam.dist, atol=1e-12)

    # Blender's own projection agrees with the OpenCV model (no distortion).
    scene = bpy.context.scene
    for cam, obj in zip(cams, objs, strict=True):
        bc._apply_render_settings(scene, obj)
        ideal = Camera(cam.name, cam.size, cam.K, np.zeros(5), cam.R, cam.t)
        xyz = cam.center + (rng.uniform(-0.3, 0.3, (20, 3)) + [0, 0, 4]) @ cam.R
        uv = ideal.project(xyz)
        W, H = cam.size
        uv_bl = []
        for p in xyz:
            q = world_to_camera_view(scene, obj, Vector(p.tolist()))
            uv_bl.append([q.x * W - 0.5, (1.0 - q.y) * H - 0.5])
        np.testing.assert_allclose(np.array(uv_bl), uv, atol=2e-3)


@pytest.mark.blender
def test_clicked_joints_placed_at_their_intersection(empty_blend):
    from addon import pipeline
    from core.scene import load_scene
    from tests.conftest import DEFAULT_SCENE

    if not (DEFAULT_SCENE / "clicks.json").is_file() or not (DEFAULT_SCENE / "truth.npz").is_file():
        pytest.skip("default scene without clicks/truth")
    empties = pipeline.place_clicks(DEFAULT_SCENE)
    sc = load_scene(DEFAULT_SCENE, check_images=False)
    truth = sc.truth
    names = [str(n) for n in truth["joint_names"]]
    frame = sc.clicks()["frame"]
    assert set(empties) == set(sc.clicks()["joints"])
    got = pipeline.clicked_positions()
    for joint, xyz in got.items():
        err = np.linalg.norm(xyz - truth["joints_xyz"][frame, names.index(joint)])
        assert err < 0.03, (joint, err)  # clicks carry a few pixels of noise
    # drawn as the 3σ ellipsoid of 1 px clicks: on line3 long along the cameras' view
    from core.intersect import triangulate

    cams = sc.calibration()
    uv = np.array([[sc.clicks()["joints"]["l_knee"][c.name] for c in cams]])
    cov = triangulate(cams, uv, sigma_px=1.0).cov[0]
    w, v = np.linalg.eigh(cov)
    e = empties["l_knee"]
    M = np.array(e.matrix_world)[:3, :3]
    long_axis = M[:, 2] / np.linalg.norm(M[:, 2])
    assert abs(long_axis @ v[:, 2]) > 0.999
    assert np.allclose(np.linalg.norm(M, axis=0), np.maximum(3 * np.sqrt(w), 0.01))
    sig = np.array(e["somacap_sigma_mm"])
    assert sig[2] > 2.5 * sig[1] and sig[1] > 1.0
    empties["l_knee"].location.x += 0.1  # the user drags an empty
    assert pipeline.clicked_positions()["l_knee"][0] == pytest.approx(got["l_knee"][0] + 0.1)


@pytest.mark.blender
def test_place_key_joints_operator_reports_the_clicks_precision(empty_blend, capfd):
    """The panel's button places the empties and says how well the clicks fix them."""
    import addon
    from tests.conftest import DEFAULT_SCENE

    if not (DEFAULT_SCENE / "clicks.json").is_file():
        pytest.skip("default scene without clicks")
    addon.register()
    try:
        bpy = empty_blend
        bpy.context.scene.somacap.scene_dir = str(DEFAULT_SCENE)
        assert bpy.ops.somacap.place_clicks() == {"FINISHED"}
        placed = [o for o in bpy.data.objects if o.name.startswith("click_")]
        assert len(placed) >= 15
    finally:
        addon.unregister()
    import re

    text = capfd.readouterr()
    m = re.search(r"±([\d.]+) mm across, ±([\d.]+) mm along the long axis", text.out + text.err)
    assert m, text.out[-400:]
    across, depth = float(m.group(1)), float(m.group(2))
    assert 1.0 < across < 10.0 and depth > 2.5 * across  # line3: depth seen worst


@pytest.mark.blender
def test_a_dragged_key_joint_is_what_the_fit_starts_from(empty_blend, tmp_path, monkeypatch):
    """The user drags the left knee's empty 2 cm along its long axis: the next fit takes
    the knee there (its clicks re-projected from the dragged point, in memory), the other
    joints where they were clicked; clicks.json is not touched."""
    from addon import pipeline
    from core import fit_scene
    from core.fit_init import triangulate_clicks
    from tests.addon.state_fixtures import synthetic_state
    from tests.conftest import DEFAULT_SCENE

    if not (DEFAULT_SCENE / "clicks.json").is_file():
        pytest.skip("default scene without clicks")
    before = (DEFAULT_SCENE / "clicks.json").read_bytes()
    empties = pipeline.place_clicks(DEFAULT_SCENE)
    assert pipeline.moved_clicks(DEFAULT_SCENE) == {}
    e = empties["l_knee"]
    M = np.array(e.matrix_world)[:3, :3]
    target = np.array(e.location) + 0.02 * M[:, 2] / np.linalg.norm(M[:, 2])
    e.location = target.tolist()
    moved = pipeline.moved_clicks(DEFAULT_SCENE)
    assert list(moved) == ["l_knee"] and np.allclose(moved["l_knee"], target)

    seen = {}

    def fake_fit_scene(sc, progress=None, **kwargs):
        seen["clicks"] = sc.clicks()
        seen["cams"] = sc.calibration()
        return synthetic_state(3, seed=2)

    monkeypatch.setattr(fit_scene, "fit_scene", fake_fit_scene)
    st = pipeline.state_for_scene(DEFAULT_SCENE, clicks_xyz=moved)
    assert st.n_frames == 3  # refitted although the scene may hold a fit.json
    cp = triangulate_clicks(seen["clicks"], seen["cams"])
    placed = pipeline.clicked_positions()
    for j, x in zip(cp.names, cp.xyz, strict=True):
        assert np.linalg.norm(x - placed[j]) < 1e-4, j
    assert (DEFAULT_SCENE / "clicks.json").read_bytes() == before
