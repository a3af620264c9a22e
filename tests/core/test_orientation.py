import numpy as np
import pytest

from core.errors import InputError
from core.orientation import initial_orientation, relabel
from tests.core.wand_truth import rig, similarity, wand_capture


@pytest.mark.parametrize("kind", ["line3", "ring4"])
def test_orientation_from_nothing_close_to_truth(kind):
    cams = rig(kind)
    xyz, uv, _ = wand_capture(cams, n=100, noise_px=0.1, outlier_frac=0.03, seed=2)
    rng = np.random.default_rng(0)
    swap = rng.random(uv.shape[:2]) < 0.5  # labels inconsistent across cameras
    uv[swap] = uv[swap][:, ::-1]
    init = initial_orientation(uv, [c.size for c in cams], 0.5)
    centers = np.array([c.center for c in init.cameras])
    truth = np.array([c.center for c in cams])
    s, R, t = similarity(centers, truth)
    assert abs(s - 1) < 0.25  # metric scale from L, focal length guessed
    assert np.max(np.linalg.norm(s * centers @ R.T + t - truth, axis=1)) < 0.5
    # labels made consistent: the intersected bars have about the right length
    both = np.all(np.isfinite(init.uv), axis=(2, 3)).sum(axis=1) >= 2
    d = np.linalg.norm(init.xyz[both, 0] - init.xyz[both, 1], axis=1)
    assert np.median(np.abs(d - 0.5)) < 0.05


def test_too_few_common_locations_is_an_input_error():
    cams = rig("line3")
    _, uv, _ = wand_capture(cams, n=30, seed=1)
    uv[5:, 1] = np.nan
    with pytest.raises(InputError, match="fewer than 8 wand locations"):
        initial_orientation(uv, [c.size for c in cams], 0.5)


def test_relabel_uses_every_camera_pair():
    """A bar imaged along an epipolar line of one pair is labelled by the other pairs."""
    cams = rig("line3")
    _, uv, _ = wand_capture(cams, n=150, noise_px=0.05, seed=3)
    both = np.all(np.isfinite(uv), axis=(2, 3))
    # (seed 3 holds locations whose bar camera 3 sees along an epipolar line of
    # camera 1, which the pairwise rule labelled wrongly)
    rng = np.random.default_rng(1)
    swap = rng.random(uv.shape[:2]) < 0.5
    swap &= both
    uv[swap] = uv[swap][:, ::-1]
    flip = relabel(cams, uv)
    ref = np.argmax(both, axis=1)
    expected = swap ^ swap[np.arange(len(uv)), ref][:, None]
    np.testing.assert_array_equal(flip & both, expected & both)
