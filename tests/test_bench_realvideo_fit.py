"""The real-video fit benchmark's inputs: clicks, empty-scene registration, person masks."""

import json

import cv2
import numpy as np
import pytest

from bench.realvideo_fit import CLICKS, FIT_CAMS
from bench.realvideo_inputs import (
    keep_in_region,
    load_clicks,
    person_region,
    read_empty_scene,
    read_video,
)
from core.errors import InputError


def _cameras(shared_data):
    from core.formats import read_qca

    path = shared_data / "video" / "pose2sim_single" / "calibration" / "Calib.qca.txt"
    return {c.name: c for c in read_qca(path)}


def test_clicks_give_a_consistent_initial_body(shared_data):
    from core.fit_init import initialise
    from core.landmarks import CLICK_JOINTS

    cams = _cameras(shared_data)
    clicks = load_clicks(CLICKS, list(cams))
    assert set(CLICK_JOINTS) <= set(clicks["joints"])
    init = initialise(clicks, [cams[n] for n in FIT_CAMS], gross_px=20.0)
    assert not init.clicks.dropped
    assert np.median(init.clicks.rms_px) < 10.0  # full-resolution pixels, by eye
    pts = dict(zip(init.clicks.names, init.clicks.xyz, strict=True))
    # a standing adult: head ~0.6-0.8 m above the pelvis, ankles near the floor
    assert 0.5 < pts["head"][2] - pts["pelvis"][2] < 0.9
    assert pts["l_ankle"][2] < 0.2 and pts["r_ankle"][2] < 0.2
    assert init.joint_rmse_m < 0.02


def test_bad_clicks_are_refused(tmp_path):
    path = tmp_path / "clicks.json"
    path.write_text(json.dumps({"frame": 0, "joints": {"head": {"cam09": [1, 2]}}}))
    with pytest.raises(InputError, match="unknown camera 'cam09'"):
        load_clicks(path, ["cam01"])
    path.write_text("{")
    with pytest.raises(InputError, match="not valid JSON"):
        load_clicks(path, ["cam01"])


def test_empty_scene_photo_is_registered_to_the_video(shared_data):
    data = shared_data / "video" / "pose2sim_single"
    cams = _cameras(shared_data)
    for name in ("cam01", "cam03"):  # a stretched (1080 px video) and a native photo
        empty = read_empty_scene(data, name, cams[name].size, 0.25)
        _, rgb = read_video(data / "videos" / f"{name}.mp4", cams[name].size, 1, None, 0.25)
        a = cv2.cvtColor(empty, cv2.COLOR_RGB2GRAY).astype(np.float32)
        b = cv2.cvtColor(rgb[0], cv2.COLOR_RGB2GRAY).astype(np.float32)
        (du, dv), _ = cv2.phaseCorrelate(a, b)
        assert np.hypot(du, dv) < 0.5, (name, du, dv)


def test_person_region_keeps_touching_components(rng):
    from tests.core._bodyscene import look_at

    cam = look_at("c", (0.0, -4.0, 1.0))
    box = person_region(cam, np.array([[0.0, 0.0, 0.2], [0.0, 0.0, 1.7]]))
    u0, v0, u1, v1 = box
    assert u0 < 256 < u1 and v0 < 192 < v1
    masks = np.zeros((2, 384, 512), bool)
    masks[:, 150:250, 240:270] = True  # the person
    masks[0, 10:20, 5:15] = True  # clutter far away
    out = keep_in_region(masks, box)
    assert out[:, 200, 250].all() and not out[0, 15, 10]
    assert out.sum() == masks[1].sum() * 2
