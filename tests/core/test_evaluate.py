"""Evaluation: truth as a fit scores zero; known perturbations give exactly those errors."""

import json

import cv2
import numpy as np
import pytest

from core import skeleton as sk
from core.cli import main as cli_main
from core.errors import InputError
from core.evaluate import evaluate, evaluate_state
from core.landmarks import JOINTS, METRIC_JOINTS
from core.state import write_state
from core.truth_state import truth_to_state
from tests.conftest import DEFAULT_SCENE


def _synthetic_truth(rng, nf=8):
    """Joints of a randomly proportioned subject in smooth random motion."""
    tmpl = sk.make_skeleton()
    offs = {
        j: tmpl.joint_offset[i] * (1 + 0.1 * rng.normal()) + rng.normal(0, 0.01, 3)
        for i, j in enumerate(JOINTS)
        if j != "pelvis"
    }
    skel = sk.make_skeleton(offs)
    t = np.linspace(0, 1, nf)[:, None]
    theta = 0.4 * np.sin(
        2 * np.pi * t * rng.uniform(0.5, 1.5, skel.n_dof) + rng.uniform(0, 6, skel.n_dof)
    )
    theta[:, 0] += 2.5
    theta[:, skel.dof_index("l_knee_x")] = 0.6  # a clearly bent knee
    root = np.c_[1.2 * t[:, 0], 0.1 * t[:, 0], 0.95 + 0.02 * np.sin(6 * t[:, 0])]
    xyz = sk.joint_positions(skel, theta, root, np.ones(skel.n_groups))
    return {
        "joints_xyz": xyz,
        "joint_names": np.array(JOINTS),
        "height_m": np.array(1.7),
        "frame_times": np.arange(nf) / 25.0,
    }


@pytest.fixture
def truth(rng):
    return _synthetic_truth(rng)


@pytest.fixture
def truth_state(truth):
    state, ik = truth_to_state(truth)
    return state, ik


def test_truth_as_fit_scores_zero(truth, truth_state):
    state, ik = truth_state
    assert state.joints_override is None  # a real solve, not a copy of the truth
    assert ik.max_err_m.max() < 1e-9
    ev = evaluate_state(state, truth)
    assert ev.mpjpe_mm < 0.01
    assert max(ev.per_joint_mm.values()) < 0.01
    assert ev.max_joint_error_pct_height < 1e-6
    assert max(ev.per_segment_max_deg.values()) < 1e-4
    assert ev.diverged_frames == 0 and ev.frames == 8


def test_rigid_translation_gives_its_length(truth, truth_state):
    state, _ = truth_state
    state.root_xyz = state.root_xyz + np.array([0.003, 0.004, 0.0])  # 5 mm
    ev = evaluate_state(state, truth)
    assert ev.mpjpe_mm == pytest.approx(5.0, abs=1e-6)
    for v in ev.per_joint_mm.values():
        assert v == pytest.approx(5.0, abs=1e-6)
    assert ev.max_joint_error_pct_height == pytest.approx(5.0 / 1700 * 100, rel=1e-6)
    assert ev.segment_orientation_rmse_deg < 1e-4
    assert ev.accel_error_mm < 1e-6  # a constant offset does not shake


def test_acceleration_error_is_the_jitter_of_one_frame(truth, truth_state):
    """One frame pushed by 3 mm: Δ² sees it as 3 mm once and 6 mm in its own frame;
    a diverged frame leaves its three second differences out."""
    state, _ = truth_state
    nf = state.n_frames
    state.root_xyz[3] += np.array([0.0, 0.0, 0.003])
    ev = evaluate_state(state, truth)
    assert ev.accel_error_mm == pytest.approx((3.0 + 6.0 + 3.0) / (nf - 2), abs=1e-6)
    assert ev.to_json()["accel_error_mm"] == ev.accel_error_mm
    state.quality.diverged[3] = True
    assert evaluate_state(state, truth).accel_error_mm < 1e-6


def test_longer_forearm_moves_only_the_wrist(truth, truth_state):
    state, _ = truth_state
    skel = state.skeleton
    j = skel.joint_index("l_wrist")
    off = skel.joint_offset.copy()
    off[j] *= 1 + 0.010 / np.linalg.norm(off[j])  # +10 mm along the forearm
    state.skeleton = sk.Skeleton(**{**skel.__dict__, "joint_offset": off})
    ev = evaluate_state(state, truth)
    assert ev.per_joint_mm["l_wrist"] == pytest.approx(10.0, abs=1e-6)
    assert ev.mpjpe_mm == pytest.approx(10.0 / len(METRIC_JOINTS), abs=1e-6)
    others = [v for k, v in ev.per_joint_mm.items() if k != "l_wrist"]
    assert max(others) < 1e-6
    assert ev.segment_orientation_rmse_deg < 1e-4


def test_knee_angle_gives_that_shin_rotation(truth, truth_state):
    state, _ = truth_state
    skel = state.skeleton
    k = skel.dof_index("l_knee_x")
    state.theta[:, k] += np.deg2rad(2.0)
    ev = evaluate_state(state, truth)
    assert ev.per_segment_max_deg["l_shin"] == pytest.approx(2.0, abs=1e-6)
    assert ev.per_segment_rmse_deg["l_shin"] == pytest.approx(2.0, abs=1e-6)
    assert ev.per_segment_max_deg["r_shin"] < 1e-6
    shin = np.linalg.norm(skel.joint_offset[skel.joint_index("l_ankle")])
    assert ev.per_joint_mm["l_ankle"] == pytest.approx(
        2000 * shin * np.sin(np.deg2rad(1.0)), rel=1e-6
    )


def test_a_twist_counts_in_orientation_but_not_in_direction(truth, truth_state):
    """The bent left knee turned 5° about the thigh's own axis: the thigh's frame (its
    twist read from the shin) turns 5°, its long axis not at all; the shin's axis swings
    round the thigh's and so counts in both figures, never more in direction."""
    state, _ = truth_state
    k = state.skeleton.dof_index("l_hip_z")
    state.theta[:, k] += np.deg2rad(5.0)
    ev = evaluate_state(state, truth)
    assert ev.per_segment_rmse_deg["l_thigh"] == pytest.approx(5.0, abs=1e-6)
    assert ev.per_segment_direction_rmse_deg["l_thigh"] < 1e-6
    shin_dir = ev.per_segment_direction_rmse_deg["l_shin"]
    assert 0.5 < shin_dir <= ev.per_segment_rmse_deg["l_shin"] + 1e-9
    assert ev.to_json()["segment_direction_rmse_deg"] == ev.segment_direction_rmse_deg
    assert ev.segment_direction_rmse_deg < ev.segment_orientation_rmse_deg


def test_a_bend_is_its_angle_in_direction_too(truth, truth_state):
    state, _ = truth_state
    state.theta[:, state.skeleton.dof_index("l_knee_x")] += np.deg2rad(2.0)
    ev = evaluate_state(state, truth)
    assert ev.per_segment_direction_rmse_deg["l_shin"] == pytest.approx(2.0, abs=1e-6)
    others = [v for s, v in ev.per_segment_direction_rmse_deg.items() if s != "l_shin"]
    assert max(others) < 1e-6


def test_diverged_frames_are_counted_and_left_out(truth):
    xyz = truth["joints_xyz"]
    fit = xyz.copy()
    fit[3] += 1.0  # garbage in a diverged frame
    div = np.zeros(len(xyz), bool)
    div[3] = True
    ev = evaluate(fit, xyz, list(JOINTS), 1.7, div)
    assert ev.diverged_frames == 1 and ev.mpjpe_mm == pytest.approx(0.0)
    assert np.isnan(ev.curves["mpjpe_mm"][3])


def _scene(tmp_path, truth):
    root = tmp_path / "scene"
    nf = truth["joints_xyz"].shape[0]
    (root / "images" / "cam1").mkdir(parents=True)
    for i in range(nf):
        cv2.imwrite(str(root / "images" / "cam1" / f"{i:06d}.png"), np.zeros((4, 4), np.uint8))
    (root / "scene.toml").write_text(
        f'name = "synthetic"\nfps = 25.0\nframes = {nf}\ncameras = ["cam1"]\nsize = [4, 4]\n'
    )
    np.savez(root / "truth.npz", **truth)
    return root


def test_cli_json_and_plot(truth, truth_state, tmp_path, capsys):
    scene = _scene(tmp_path, truth)
    state, _ = truth_state
    state.root_xyz = state.root_xyz + np.array([0.0, 0.0, 0.010])
    fit = write_state(tmp_path / "fit.json", state)
    png = tmp_path / "curves.png"
    assert cli_main(["evaluate", str(scene), str(fit), "--json", "--plot", str(png)]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    res = json.loads(out[-1])
    assert res["mpjpe_mm"] == pytest.approx(10.0, abs=1e-6)
    assert res["frames"] == 8 and res["diverged_frames"] == 0
    assert set(res["per_joint_mm"]) == set(METRIC_JOINTS)
    assert res["segment_orientation_rmse_deg"] < 1e-4
    assert res["segment_direction_rmse_deg"] < 1e-4
    assert any("MPJPE" in line and "10.000 mm" in line for line in out)
    assert any(line.startswith("segment direction RMSE") for line in out)
    assert png.read_bytes()[:4] == b"\x89PNG"


def test_cli_frame_mismatch_is_a_clear_error(truth, truth_state, tmp_path, capsys):
    scene = _scene(tmp_path, truth)
    state, _ = truth_state
    state.theta, state.root_xyz = state.theta[:5], state.root_xyz[:5]
    state.quality.rmse_m = state.quality.rmse_m[:5]
    state.quality.theta_sigma = state.quality.theta_sigma[:5]
    state.quality.converged = state.quality.converged[:5]
    state.quality.diverged = state.quality.diverged[:5]
    state.quality.cameras = state.quality.cameras[:5]
    fit = write_state(tmp_path / "fit.json", state)
    with pytest.raises(InputError, match=r"fit\.json: has 5 frames but .*truth\.npz has 8"):
        evaluate_state(state, truth, scene / "truth.npz", fit)
    assert cli_main(["evaluate", str(scene), str(fit)]) == 2
    assert "fit.json: has 5 frames" in capsys.readouterr().err


def test_truth_missing_joint(truth):
    names = truth["joint_names"].copy()
    names[names == "l_knee"] = "knee"
    with pytest.raises(InputError, match=r"truth\.npz: joint_names lacks the metric joints"):
        evaluate_state(None, {**truth, "joint_names": names})


@pytest.mark.slow
def test_default_scene_truth_scores_zero_and_offsets_exactly():
    if not (DEFAULT_SCENE / "truth.npz").is_file():
        pytest.skip(f"default scene not rendered yet at {DEFAULT_SCENE}")
    from core.scene import load_scene

    scene = load_scene(DEFAULT_SCENE, check_images=False)
    state, ik = truth_to_state(scene.truth, scene.fps)
    ev = evaluate_state(state, scene.truth)
    assert ev.mpjpe_mm < 0.01 and max(ev.per_segment_max_deg.values()) < 1e-3
    state.root_xyz = state.root_xyz + np.array([0.0, 0.006, 0.008])
    if state.joints_override is not None:
        state.joints_override = state.joints_override + np.array([0.0, 0.006, 0.008])
    ev = evaluate_state(state, scene.truth)
    assert ev.mpjpe_mm == pytest.approx(10.0, abs=1e-6)


def test_mesh_samples_lie_on_the_triangles_spread_by_area():
    """Two triangles in the z = 0 plane, the second three times the first's area: the
    samples lie inside them, about a quarter on the first."""
    from core.evaluate import sample_mesh_surface

    v = np.array(
        [
            [0, 0, 0],
            [1, 0, 0],
            [0, 1, 0],  # area 0.5
            [2, 0, 0],
            [5, 0, 0],
            [2, 1, 0],
        ],
        float,
    )  # area 1.5
    faces = np.array([[0, 1, 2], [3, 4, 5]])
    p = sample_mesh_surface(v, faces, 20000, np.random.default_rng(0))
    assert p.shape == (20000, 3) and np.all(p[:, 2] == 0)
    first = p[:, 0] < 1.5
    x, y = p[first, 0], p[first, 1]
    assert np.all((x >= 0) & (y >= 0) & (x + y <= 1 + 1e-12))
    x, y = p[~first, 0] - 2, p[~first, 1]
    assert np.all((x >= 0) & (y >= 0) & (x / 3 + y <= 1 + 1e-12))
    assert abs(first.mean() - 0.25) < 0.01
