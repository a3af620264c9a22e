"""Background model and foreground masks on seeded synthetic frames."""

import cv2
import numpy as np
import pytest

from core.background import fit_background
from core.errors import InputError


def _frames(rng, n=30, h=96, w=128, still=False):
    """Textured background, a person-like blob moving (or standing), a cast shadow, noise."""
    bg = cv2.GaussianBlur(rng.uniform(40, 220, (h, w, 3)).astype(np.float32), (0, 0), 3)
    frames, masks = [], []
    for i in range(n):
        img = bg.copy()
        cx = 24 + (0 if still and i < n * 0.4 else (80 * i) // n)
        mask = np.zeros((h, w), np.uint8)
        cv2.ellipse(mask, (cx, 50), (10, 30), 0, 0, 360, 1, -1)
        shadow = np.zeros((h, w), np.uint8)
        cv2.ellipse(shadow, (cx + 14, 84), (8, 4), 0, 0, 360, 1, -1)
        img[shadow.astype(bool)] *= 0.6
        person = np.array([200.0, 60.0, 90.0]) + rng.normal(0, 10, (h, w, 3))
        img[mask.astype(bool)] = person[mask.astype(bool)]
        img += rng.normal(0, 2.0, img.shape)
        frames.append(np.clip(img, 0, 255).astype(np.uint8))
        masks.append(mask.astype(bool))
    return np.array(frames), np.array(masks)


def _iou(a, b):
    return (a & b).sum() / max(1, (a | b).sum())


@pytest.mark.parametrize("still", [False, True])
def test_foreground_iou_with_shadows(rng, still):
    frames, masks = _frames(rng, still=still)
    model = fit_background(frames)
    ious = [_iou(model.foreground(f), m) for f, m in zip(frames, masks, strict=True)]
    # a person standing still for 40 % of the take must not burn into the background
    assert np.mean(ious) > 0.93, np.round(ious, 3)
    assert min(ious) > 0.85


def test_empty_frames_define_background(rng):
    frames, masks = _frames(rng, n=10)
    empty = frames.copy()
    for e in empty:
        e[:] = np.median(frames, axis=0).astype(np.uint8)  # an approximately empty plate
    model = fit_background(frames, empty=empty[:3])
    assert _iou(model.foreground(frames[5]), masks[5]) > 0.9


def test_size_mismatch_is_clear(rng):
    frames, _ = _frames(rng, n=5)
    model = fit_background(frames)
    with pytest.raises(InputError, match="does not match the background model"):
        model.foreground(frames[0][:50])


def test_no_frames_is_clear():
    with pytest.raises(InputError, match="at least one frame"):
        fit_background(np.zeros((0, 10, 10, 3), np.uint8))


def test_known_person_pixels_free_a_long_standing_background(rng):
    """Standing still for 60 % of the take burns the person into a plain median; masks of
    where the person is (e.g. the projected fitted body, dilated) free it."""
    frames, masks = _frames(rng, n=30, still=True)
    # make the still phase 60 % long
    frames[:18] = frames[0]
    masks[:18] = masks[0]
    plain = fit_background(frames)
    assert _iou(plain.foreground(frames[0]), masks[0]) < 0.5
    dilated = np.array(
        [cv2.dilate(m.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0 for m in masks]
    )
    guided = fit_background(frames, exclude=dilated)
    ious = [_iou(guided.foreground(f), m) for f, m in zip(frames, masks, strict=True)]
    assert min(ious) > 0.85, np.round(ious, 3)


def _approaching(rng, n=40, h=96, w=128):
    """A textured person who stays in front of the camera and grows (walking towards
    it): the middle of the body covers its pixels in ~90 % of the frames, with the
    clothing's pattern (reds and browns) moving over them (grey backdrop, noise σ 2)."""
    bg = np.full((h, w, 3), 115.0, np.float32)
    cloth = rng.uniform([0, 0, 0], [255, 90, 90], (3 * h, 3 * w, 3)).astype(np.float32)
    cloth = cv2.resize(
        cv2.resize(cloth, (w // 2, h // 2)), (3 * w, 3 * h), interpolation=cv2.INTER_NEAREST
    )
    frames, masks = [], []
    for i in range(n):
        img = bg.copy()
        mask = np.zeros((h, w), np.uint8)
        if i >= 0.1 * n:  # enters after the first few frames
            ax = (12 + (10 * i) // n, 26 + (14 * i) // n)
            cv2.ellipse(mask, (64 + (i % 5) - 2, 50), ax, 0, 0, 360, 1, -1)
        m = mask.astype(bool)
        dy, dx = (7 * i) % (2 * h), (11 * i) % (2 * w)  # the pattern moves
        img[m] = cloth[dy : dy + h, dx : dx + w][m]
        img += rng.normal(0, 2.0, img.shape)
        frames.append(np.clip(img, 0, 255).astype(np.uint8))
        masks.append(m)
    return np.array(frames), np.array(masks)


def test_a_person_covering_pixels_most_of_the_take_does_not_burn_in(rng):
    frames, masks = _approaching(rng)
    covered = masks.mean(axis=0)
    assert (covered[masks[-1]] > 0.8).mean() > 0.3  # the case this is about
    model = fit_background(frames)
    late = range(len(frames) // 2, len(frames))
    ious = [_iou(model.foreground(frames[i]), masks[i]) for i in late]
    assert np.mean(ious) > 0.9, np.round(ious, 3)
    # a temporal median cannot: more than half of the frames show the person there
    med = np.median(frames, axis=0)
    off = np.linalg.norm(med.astype(float) - 115.0, axis=2) > 20
    assert off[masks[-1]].mean() > 0.2
    # the noise level stays that of the camera, not of the person's pattern
    assert np.median(model.sigma[masks[-1]]) < 4.0
