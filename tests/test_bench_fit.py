"""The benchmark's studio clip windows lie inside their clips and show their motion."""

import numpy as np

from bench.fit import FPS, FRAMES, STUDIO_SCENES
from sample_scenes.bvh import read_bvh

CMU_SCALE = 0.056444  # CMU units -> metres (../shared/data/README.md)


def _window(shared_data, name):
    bvh_name, _, start = STUDIO_SCENES[name]
    bvh = read_bvh(shared_data / "mocap" / bvh_name)
    end = start + round((FRAMES - 1) / FPS / bvh.frame_time)
    assert end < bvh.n_frames
    return bvh.root_positions(CMU_SCALE)[start:end + 1]


def test_every_window_fits_its_clip(shared_data):
    for name in STUDIO_SCENES:
        _window(shared_data, name)


def test_jump_window_holds_a_jump(shared_data):
    hips = _window(shared_data, "jumps_line3")
    up = hips[:, 2]
    # standing at the start, hips well above standing height in flight, forward motion
    assert up.max() - up[0] > 0.15
    assert np.linalg.norm(hips[-1, :2] - hips[0, :2]) > 0.3


def test_default_dance_windows_start_upright(shared_data):
    from bench.fit import DEFAULT_SET

    for name in DEFAULT_SET:
        bvh_name, _, start = STUDIO_SCENES[name]
        if bvh_name != "05_06.bvh":
            continue
        bvh = read_bvh(shared_data / "mocap" / bvh_name)
        _, xyz = bvh.sample(np.array([start * bvh.frame_time]), CMU_SCALE)
        assert xyz[0, bvh.index("Head"), 2] - xyz[0, bvh.index("Hips"), 2] > 0.3
