"""Repairing a burnt-in temporal-median background with an empty-scene image."""

import cv2
import numpy as np
import pytest

from core.background import fit_background, with_reference
from core.errors import InputError


def _scene(rng, n=30, h=80, w=100, still_frac=0.7):
    """A person-like blob that stands still for ``still_frac`` of the take, then walks
    out; the empty background (with a slightly different exposure) is returned too."""
    bg = cv2.GaussianBlur(rng.uniform(60, 200, (h, w, 3)).astype(np.float32), (0, 0), 2)
    frames, masks = [], []
    for i in range(n):
        img = bg.copy()
        cx = 30 if i < still_frac * n else 30 + 8 * (i - int(still_frac * n) + 1)
        mask = np.zeros((h, w), np.uint8)
        cv2.ellipse(mask, (cx, 40), (8, 25), 0, 0, 360, 1, -1)
        img[mask.astype(bool)] = np.array([210.0, 150.0, 120.0]) + rng.normal(0, 4, (3,))
        img += rng.normal(0, 2.0, img.shape)
        frames.append(np.clip(img, 0, 255).astype(np.uint8))
        masks.append(mask.astype(bool))
    empty = np.clip(bg * 0.93 + rng.normal(0, 2.0, bg.shape), 0, 255).astype(np.uint8)
    return np.array(frames), np.array(masks), empty


def _iou(a, b):
    return (a & b).sum() / max(1, (a | b).sum())


def test_reference_frees_a_burnt_in_person(rng):
    frames, masks, empty = _scene(rng)
    model = fit_background(frames)
    before = _iou(model.foreground(frames[5]), masks[5])
    fixed = with_reference(model, frames, empty)
    after = [_iou(fixed.foreground(f), m) for f, m in zip(frames, masks, strict=True)]
    assert before < 0.5  # the person stood there in 70 % of the frames
    assert min(after) > 0.85, np.round(after, 2)


def test_person_only_in_the_reference_is_not_copied(rng):
    frames, masks, empty = _scene(rng, still_frac=0.0)  # the take's median is clean
    other = empty.copy()
    cv2.circle(other, (80, 60), 8, (20, 220, 20), -1)  # someone standing in the photo only
    model = fit_background(frames)
    fixed = with_reference(model, frames, other)
    np.testing.assert_array_equal(fixed.colour[60, 80], model.colour[60, 80])
    assert not fixed.foreground(frames[0])[50:70, 70:90].any()


def test_reference_size_mismatch_is_clear(rng):
    frames, _, empty = _scene(rng, n=6)
    with pytest.raises(InputError, match="does not match the background model"):
        with_reference(fit_background(frames), frames, empty[:40])
