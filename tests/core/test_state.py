"""Fitted-state file: round trip and validation with clear errors naming the file."""

import json

import numpy as np
import pytest

from core import metaball_surface as mbs
from core import metaballs as mb
from core import skeleton as sk
from core.errors import InputError
from core.landmarks import JOINTS
from core.state import FitState, Quality, bone_world_matrices, read_state, write_state


@pytest.fixture
def state(rng):
    skel = sk.make_skeleton()
    nf = 4
    s = 1.0 + 0.05 * rng.normal(size=skel.n_groups)
    q = Quality.empty(nf, skel.n_dof)
    q.rmse_m[:] = [0.001, 0.002, np.nan, 0.001]
    q.diverged[2] = True
    q.cameras[0] = {"l_shoulder": ["cam1", "cam2"]}
    return FitState(
        skeleton=skel,
        s=s,
        metaballs=mb.make_metaballs(skel),
        fps=25.0,
        root_xyz=rng.normal(0, 1, (nf, 3)),
        theta=rng.normal(0, 0.3, (nf, skel.n_dof)),
        quality=q,
        source_scene="synthetic",
    )


def test_round_trip(state, tmp_path):
    path = write_state(tmp_path / "fit.json", state)
    back = read_state(path)
    np.testing.assert_array_equal(back.theta, state.theta)
    np.testing.assert_array_equal(back.root_xyz, state.root_xyz)
    np.testing.assert_array_equal(back.s, state.s)
    np.testing.assert_array_equal(back.metaballs.radii, state.metaballs.radii)
    np.testing.assert_allclose(back.joints_xyz(), state.joints_xyz(), atol=1e-12)
    assert np.isnan(back.quality.rmse_m[2]) and back.quality.diverged.tolist() == [0, 0, 1, 0]
    assert back.quality.cameras[0] == {"l_shoulder": ["cam1", "cam2"]}
    names, M = bone_world_matrices(back)
    assert names == state.skeleton.bone_names and M.shape == (4, len(names), 4, 4)
    assert back.joints_xyz(JOINTS[:3]).shape == (4, 3, 3)
    assert back.quality.unobserved is None  # optional: absent when not given


def test_unobserved_angles_round_trip_and_are_validated(state, tmp_path):
    n = state.skeleton.n_dof
    state.quality.unobserved = np.zeros((4, n), bool)
    state.quality.unobserved[1:3, state.skeleton.dof_index("r_elbow_x")] = True
    back = read_state(write_state(tmp_path / "fit.json", state))
    np.testing.assert_array_equal(back.quality.unobserved, state.quality.unobserved)
    data = json.loads((tmp_path / "fit.json").read_text())
    data["quality"]["unobserved"][2] = data["quality"]["unobserved"][2][:-1]
    with pytest.raises(InputError, match=rf"quality\.unobserved must be 4 lists of {n}"):
        read_state(_write(tmp_path, data))


def _write(tmp_path, data):
    p = tmp_path / "fit.json"
    p.write_text(json.dumps(data))
    return p


@pytest.fixture
def data(state, tmp_path):
    return json.loads(write_state(tmp_path / "ok.json", state).read_text())


def test_missing_key(data, tmp_path):
    del data["motion"]["theta"]
    with pytest.raises(InputError, match=r"fit\.json: is missing the key 'theta'"):
        read_state(_write(tmp_path, data))


def test_newer_version(data, tmp_path):
    data["version"] = 99
    with pytest.raises(InputError, match=r"fit\.json: .*written by a newer Somacap"):
        read_state(_write(tmp_path, data))


def test_nan(data, tmp_path):
    data["motion"]["root_xyz"][0][0] = 12345.5
    p = tmp_path / "fit.json"
    p.write_text(json.dumps(data).replace("12345.5", "NaN", 1))
    with pytest.raises(InputError, match=r"fit\.json: 'root_xyz' contains NaN"):
        read_state(p)


def test_null_angle(data, tmp_path):
    data["motion"]["theta"][2][5] = None
    with pytest.raises(InputError, match=r"fit\.json: 'theta' contains NaN"):
        read_state(_write(tmp_path, data))


def test_wrong_shape(data, tmp_path):
    data["motion"]["theta"] = data["motion"]["theta"][:-1]
    with pytest.raises(InputError, match=r"fit\.json: 'theta' has shape \[3, 47\], expected 4x47"):
        read_state(_write(tmp_path, data))


def test_wrong_format_and_garbage(data, tmp_path):
    data["format"] = "other"
    with pytest.raises(InputError, match="not a Somacap fitted state"):
        read_state(_write(tmp_path, data))
    p = tmp_path / "bad.json"
    p.write_text("{not json")
    with pytest.raises(InputError, match=r"bad\.json: not valid JSON"):
        read_state(p)
    with pytest.raises(InputError, match="not found"):
        read_state(tmp_path / "nope.json")


def test_writer_refuses_nan(state, tmp_path):
    state.theta[1, 3] = np.nan
    with pytest.raises(ValueError, match="non-finite theta"):
        write_state(tmp_path / "fit.json", state)


def test_deflated_metaballs_round_trip_and_bad_scale(state, tmp_path):
    from dataclasses import replace

    skel = state.skeleton
    flat = mbs.deflate(skel, state.metaballs, state.s)
    back = read_state(write_state(tmp_path / "fit.json", replace(state, metaballs=flat)))
    np.testing.assert_array_equal(back.metaballs.visible_scale, flat.visible_scale)
    np.testing.assert_allclose(back.metaballs.visible, state.metaballs.visible)
    data = json.loads((tmp_path / "fit.json").read_text())
    data["metaballs"]["items"][3]["visible_scale"] = [0.5, -1.0, 0.5]
    with pytest.raises(InputError, match=r"fit\.json: metaball visible_scale must be"):
        read_state(_write(tmp_path, data))
    del data["metaballs"]["items"][4]["visible_scale"]
    with pytest.raises(InputError, match=r"fit\.json: the metaballs are malformed"):
        read_state(_write(tmp_path, data))
