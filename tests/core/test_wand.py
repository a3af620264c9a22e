import numpy as np

from core.wand import detect_targets, label_sequence


def _gauss_image(centers, size=(96, 64), sigma=1.2, noise=2.0, rng=None):
    h, w = size[1], size[0]
    vv, uu = np.indices((h, w))
    img = np.full((h, w), 12.0)
    for u, v in centers:
        img += 220.0 * np.exp(-((uu - u) ** 2 + (vv - v) ** 2) / (2 * sigma**2))
    if rng is not None:
        img += rng.normal(scale=noise, size=img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


def test_subpixel_centroids(rng):
    truth = rng.uniform([10, 10], [86, 54], size=(40, 2, 2))
    truth[:, 1, 0] = np.where(
        np.abs(truth[:, 1, 0] - truth[:, 0, 0]) < 12, (truth[:, 0, 0] + 30) % 80 + 8, truth[:, 1, 0]
    )
    errs = []
    for pair in truth:
        found = detect_targets(_gauss_image(pair, rng=rng))
        assert found.shape == (2, 2)
        ref = pair[np.argsort(pair[:, 0])]
        errs.append(found - ref)
    assert np.sqrt(np.mean(np.square(errs))) < 0.1


def test_missing_and_merged_targets_are_dropped_and_counted(rng):
    one = detect_targets(_gauss_image([(30, 30)], rng=rng))
    merged = detect_targets(_gauss_image([(30, 30), (31.5, 30)], rng=rng))
    assert len(one) == 1 and len(merged) == 1
    uv, counts = label_sequence([one, np.array([[10.0, 10.0], [50.0, 40.0]]), merged])
    np.testing.assert_array_equal(counts, [1, 2, 1])
    assert np.isnan(uv[0]).all() and np.isnan(uv[2]).all() and np.isfinite(uv[1]).all()


def test_labels_follow_continuity():
    a = np.array([[40.0, 10.0], [10.0, 40.0]])
    seq = [a, (a + [1.0, 1.0])[np.argsort((a + 1.0)[:, 0])], a + [2.0, 1.5]]
    seq = [s[np.argsort(s[:, 0])] for s in seq]  # detector order: left to right
    uv, _ = label_sequence(seq)
    d = np.linalg.norm(np.diff(uv, axis=0), axis=2)
    assert np.all(d < 3.0)  # A stays A
