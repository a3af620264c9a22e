"""bench.selection helpers: the Daz -> CMU renaming of a BVH and the camera agreement."""

import numpy as np

from bench.selection import DAZ_TO_CMU, camera_agreement, renamed_bvh

BVH = """HIERARCHY
ROOT hip
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT lThigh
  {
    OFFSET 4 -2 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    JOINT lShin
    {
      OFFSET 0 -18 0
      CHANNELS 3 Zrotation Xrotation Yrotation
      End Site
      {
        OFFSET 0 -17 0
      }
    }
  }
  JOINT leftEye
  {
    OFFSET 1 30 2
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 0 1
    }
  }
}
MOTION
Frames: 1
Frame Time: 0.00833333
0 36 0 0 0 0 1 2 3 4 5 6 7 8 9
"""


def test_renamed_bvh_maps_daz_joints_and_keeps_the_rest(tmp_path):
    src = tmp_path / "daz.bvh"
    src.write_text(BVH)
    out = renamed_bvh(src, tmp_path / "sub" / "cmu.bvh").read_text()
    assert "ROOT Hips" in out and "JOINT LeftUpLeg" in out and "JOINT LeftLeg" in out
    assert "JOINT leftEye" in out  # no CMU counterpart: unchanged
    assert out.split("MOTION")[1] == BVH.split("MOTION")[1]
    assert len(out.splitlines()) == len(BVH.splitlines())
    assert DAZ_TO_CMU["rShldr"] == "RightArm" and DAZ_TO_CMU["lCollar"] == "LeftShoulder"


def test_camera_agreement_counts_hidden_used_and_seen_unused():
    ref = np.array([[[0.9, 0.1, np.nan], [0.5, 0.05, 0.3]]])  # (F=1, P=2, C=3)
    use = np.array([[[True, True, True], [False, False, True]]])
    hidden_used, seen_unused = camera_agreement(use, ref)
    # scored used part-views: (0,0) seen, (0,1) hidden, (1,2) seen -> 1 of 3 hidden
    assert np.isclose(hidden_used, 1 / 3)
    # seen part-views: (0,0), (1,0), (1,2) -> (1,0) unused
    assert np.isclose(seen_unused, 1 / 3)


class _Stop(Exception):
    """Raised by the stand-in fit once it has recorded its call."""


class _Scene:
    truth = {}
    n_frames = 3

    def calibration(self):
        return []


def _stop_at_the_fit(monkeypatch, what):
    """Replace core's ``run_scene`` by a stand-in that records ``what(kwargs)`` and
    stops; returns the list it records into."""
    seen = []

    def fake_fit(scene, **kw):
        seen.append(what(kw))
        raise _Stop

    monkeypatch.setattr("core.fit_scene.run_scene", fake_fit)
    return seen


def test_fit_rows_pass_the_cues_to_the_fit(monkeypatch):
    """``--cues both`` fits with the tracked points as well; the EKF cannot take them."""
    import pytest

    import bench.selection as sel

    with pytest.raises(SystemExit):
        sel.main(["--cues", "both", "--scenes", "x"])  # the EKF rows: refused up front

    seen = _stop_at_the_fit(
        monkeypatch, lambda kw: (kw["cues"], kw["observations"], kw["contour_settings"].select)
    )
    with pytest.raises(_Stop):
        sel._fit_rows(_Scene(), 3, 100.0, [0], None, cues="both")
    assert seen == [("both", "tracks", True)]


def test_click_draw_moves_the_clicks_as_fit_spread_does(monkeypatch):
    import bench.selection as sel
    from bench.fit_spread import perturbed_clicks

    clicks = {
        "frame": 0,
        "joints": {"head": {"cam1": [10.0, 20.0]}, "pelvis": {"cam1": [5.0, 6.0]}},
    }

    class _Scene:
        truth = {}
        n_frames = 3

        def clicks(self):
            return clicks

        def calibration(self):
            return []

    monkeypatch.setattr(sel, "scene_dir", lambda name, fps=None: name)
    monkeypatch.setattr("core.scene.load_scene", lambda path: _Scene())
    monkeypatch.setattr(sel, "truth_visibility", lambda scene, frames: None)
    got = []
    monkeypatch.setattr(sel, "_fit_rows", lambda scene, *a: got.append(scene.clicks()) or [])
    for draw in (0, 2):
        sel.run_scene("x", 3, tracker="fit", cues="both", click_draw=draw)
    assert got[0] is clicks
    want = perturbed_clicks(clicks, 0.5, 2)["joints"]["head"]["cam1"]
    np.testing.assert_array_equal(got[1]["joints"]["head"]["cam1"], want)
    assert not np.allclose(want, clicks["joints"]["head"]["cam1"])


def test_rows_pick_the_fit_rows_by_number(monkeypatch):
    """``--rows 2,4``: only the fused row and the default's (left-out views at 2 σ) run;
    numbers outside the rows, or rows without the fit, are refused up front."""
    import pytest

    import bench.selection as sel

    for bad in (["--rows", "9", "--tracker", "fit"], ["--rows", "2"], ["--rows", "a,b"]):
        with pytest.raises(SystemExit):
            sel.main(bad + ["--scenes", "x"])
    seen = _stop_at_the_fit(
        monkeypatch,
        lambda kw: (
            kw["contour_settings"].select,
            kw["contour_settings"].wide_view_deg,
            kw["contour_settings"].unselected_sigma_scale,
        ),
    )
    for k in (2, 4):
        with pytest.raises(_Stop):
            sel._fit_rows(_Scene(), 3, 100.0, [0], None, cues="both", which={k})
    assert seen == [(False, 60.0, None), (True, 60.0, 2.0)]
