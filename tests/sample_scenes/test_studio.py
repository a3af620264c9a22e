"""End to end: the studio renders a tiny scene whose truth agrees with its images."""

from __future__ import annotations

import subprocess
import sys

import cv2
import numpy as np
import pytest

from core.landmarks import JOINTS, METRIC_JOINTS
from core.scene import load_scene
from sample_scenes.bvh import CMU_SCALE, read_bvh
from tests.conftest import REPO

pytestmark = pytest.mark.blender


def _studio(*args, check=True):
    pytest.importorskip("bpy")
    proc = subprocess.run(
        [sys.executable, "-m", "sample_scenes.studio", *map(str, args)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )
    if check and proc.returncode != 0:
        raise AssertionError(proc.stderr[-3000:])
    return proc


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    from tests.conftest import SHARED_DATA

    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared data not found at {SHARED_DATA}")
    out = tmp_path_factory.mktemp("studio") / "tiny"
    _studio(
        "--out",
        out,
        "--size",
        "64x48",
        "--frames",
        3,
        "--start",
        60,
        "--wand-positions",
        5,
        "--seed",
        3,
    )
    return load_scene(out)


def _inside(mask: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Whether each rounded ``uv`` (N, 2) lies in ``mask`` dilated by one pixel."""
    grown = cv2.dilate(mask.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    iu = np.clip(np.round(uv[:, 0]).astype(int), 0, mask.shape[1] - 1)
    iv = np.clip(np.round(uv[:, 1]).astype(int), 0, mask.shape[0] - 1)
    return grown[iv, iu]


def test_truth_joints_project_into_masks(tiny):
    cams = tiny.calibration()
    truth = tiny.truth
    masks = tiny.truth_masks()
    assert masks.shape == (len(cams), 3, 48, 64)
    assert list(truth["joint_names"]) == list(JOINTS)
    idx = [JOINTS.index(j) for j in METRIC_JOINTS]
    for c, cam in enumerate(cams):
        for f in range(tiny.n_frames):
            uv = cam.project(truth["joints_xyz"][f, idx])
            assert _inside(masks[c, f], uv).all(), (cam.name, f)
            # The person fills most of the image height (framing from the motion volume).
            rows = np.flatnonzero(masks[c, f].any(axis=1))
            assert rows[-1] - rows[0] + 1 >= 0.6 * 48
    # Skinned vertices project onto the mask too (most of them; the silhouette edge
    # is anti-aliased).
    uv = cams[0].project(truth["vertices"][0].astype(float))
    assert _inside(masks[0, 0], uv).mean() > 0.99


def test_masks_agree_with_images(tiny):
    masks = tiny.truth_masks()
    for c, cam in enumerate(tiny.cameras):
        for f in range(tiny.n_frames):
            img = tiny.image(cam, f, color=True).astype(int)
            bg = np.round(0.45 * 255)
            diff = np.abs(img - bg).max(axis=-1)
            # Beyond the anti-aliasing filter (1.5 px) the image is the bare background.
            outside = ~(cv2.dilate(masks[c, f].astype(np.uint8), np.ones((5, 5))) > 0)
            assert np.all(diff[outside] == 0)
            assert np.mean(diff[masks[c, f]] > 3) > 0.9


def test_wand_targets_project_onto_blobs(tiny):
    cams = tiny.calibration()
    frames = tiny.wand_frames()
    xyz = np.load(tiny.root / "wand_truth.npz")["xyz"]
    assert tiny.wand_length() == 0.5
    np.testing.assert_allclose(np.linalg.norm(xyz[:, 0] - xyz[:, 1], axis=1), 0.5)
    assert all(len(v) == len(xyz) for v in frames.values())
    for cam in cams:
        for i, path in enumerate(frames[cam.name]):
            img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE).astype(float)
            for uv in cam.project(xyz[i]):
                u0, v0 = np.round(uv).astype(int)
                win = img[v0 - 4 : v0 + 5, u0 - 4 : u0 + 5]
                vv, uu = np.mgrid[v0 - 4 : v0 + 5, u0 - 4 : u0 + 5]
                centroid = np.array([(uu * win).sum(), (vv * win).sum()]) / win.sum()
                assert np.linalg.norm(centroid - uv) < 0.5, (cam.name, i, centroid, uv)


def test_knees_follow_the_bvh(tiny, shared_data):
    src = tiny.meta["source"]
    bvh = read_bvh(shared_data / "mocap" / src["bvh"])
    times = src["bvh_start_frame"] * bvh.frame_time + tiny.truth["frame_times"]
    _, xyz = bvh.sample(times, CMU_SCALE)
    ref = src["retarget_scale"] * xyz + np.array(src["retarget_offset_m"])
    for joint, bone in (("l_knee", "LeftLeg"), ("r_ankle", "RightFoot")):
        got = tiny.truth["joints_xyz"][:, JOINTS.index(joint)]
        assert np.linalg.norm(got - ref[:, bvh.index(bone)], axis=1).max() < 0.04


@pytest.mark.slow
def test_interlaced_noisy_scene(tmp_path, shared_data):
    out = tmp_path / "field"
    _studio(
        "--out",
        out,
        "--size",
        "64x48",
        "--frames",
        2,
        "--interlace",
        "--noise",
        2,
        "--click-noise",
        1.5,
        "--look",
        "skin",
        "--background",
        "textured",
        "--rig",
        "orthogonal3",
        "--wand-positions",
        2,
    )
    scene = load_scene(out)
    assert scene.field == "odd" and scene.image(0, 0).shape == (24, 64)
    cams = scene.calibration()
    assert cams[0].aspect == pytest.approx(2.0)
    masks = scene.truth_masks()
    assert masks.shape == (3, 2, 24, 64)
    idx = [JOINTS.index(j) for j in METRIC_JOINTS]
    for c, cam in enumerate(cams):
        uv = cam.project(scene.truth["joints_xyz"][0, idx])
        assert _inside(masks[c, 0], uv).mean() > 0.9
    clicks = scene.clicks()
    uv = np.array([clicks["joints"]["l_knee"][cam.name] for cam in cams])
    true = np.array(
        [cam.project(scene.truth["joints_xyz"][0, JOINTS.index("l_knee")]) for cam in cams]
    )
    err = np.linalg.norm(uv - true, axis=1)
    assert err.max() > 0.01 and err.max() < 8  # noisy clicks, within a few sigma


@pytest.mark.slow
def test_bad_inputs_exit_2_naming_the_file(tmp_path, shared_data):
    garbled = tmp_path / "garbled.bvh"
    garbled.write_text("HIERARCHY\nROOT Hips\n{\n OFFSET 0 0\n")
    missing = tmp_path / "missing.bvh"
    proc = _studio("--out", tmp_path / "o1", "--bvh", garbled, check=False)
    assert proc.returncode == 2 and f"studio: error: {garbled}" in proc.stderr
    proc = _studio("--out", tmp_path / "o2", "--bvh", missing, check=False)
    assert proc.returncode == 2 and f"studio: error: {missing}: BVH file not found" in proc.stderr
    proc = _studio("--out", tmp_path / "o3", "--character", tmp_path / "none.blend", check=False)
    assert proc.returncode == 2 and "none.blend: character file not found" in proc.stderr
    # A character file holding a mesh but no armature.
    blend = tmp_path / "no_armature.blend"
    code = (
        "import bpy; bpy.ops.wm.read_factory_settings(use_empty=True); "
        "me = bpy.data.meshes.new('m'); o = bpy.data.objects.new('m', me); "
        "bpy.context.scene.collection.objects.link(o); "
        f"bpy.ops.wm.save_as_mainfile(filepath={str(blend)!r})"
    )
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, timeout=120)
    proc = _studio("--out", tmp_path / "o4", "--character", blend, check=False)
    assert proc.returncode == 2
    assert f"studio: error: {blend}: holds no armature" in proc.stderr
