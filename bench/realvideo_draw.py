"""Overlays of the real-video fit benchmark (:mod:`bench.realvideo_fit`), written as PNG.

:func:`draw_check`: the held-out camera's image with the person's mask tinted and each
fitted body's outline; :func:`draw_masks`: a grid of the person's masks, one row per
camera, one column per frame.  Images are RGB uint8 (H, W, 3), masks (H, W) bool, at
the benchmark's mask resolution (pixels).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np


def _outline(img: np.ndarray, mask: np.ndarray, colour, thick: int = 1) -> None:
    cs, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    cv2.drawContours(img, cs, -1, colour, thick, cv2.LINE_AA)


def draw_check(
    rgb: np.ndarray, person: np.ndarray, bodies: dict, path: Path, zoom: int = 2
) -> None:
    """The held-out image with the person's mask (green, tinted) and each fitted body's
    outline (colours per label), written as PNG."""
    img = rgb.copy()
    img[person] = (0.6 * img[person] + 0.4 * np.array([0, 255, 0])).astype(np.uint8)
    img = cv2.resize(img, None, fx=zoom, fy=zoom, interpolation=cv2.INTER_LINEAR)

    def big(m):
        return cv2.resize(
            m.astype(np.uint8), None, fx=zoom, fy=zoom, interpolation=cv2.INTER_NEAREST
        )

    _outline(img, big(person), (0, 200, 0), 1)
    y = 18
    for label, (mask, colour) in bodies.items():
        _outline(img, big(mask), colour, 2)
        cv2.putText(img, label, (8, y), cv2.FONT_HERSHEY_SIMPLEX, 0.55, colour, 2, cv2.LINE_AA)
        y += 22
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))


def draw_masks(rgb: dict, masks: dict, frames: list[int], path: Path) -> None:
    """Grid: one row per camera, one column per frame, the person's mask tinted red."""
    rows = []
    for name in rgb:
        tiles = []
        for f in frames:
            img = rgb[name][f].copy()
            m = masks[name][f]
            img[m] = (0.5 * img[m] + 0.5 * np.array([255, 0, 0])).astype(np.uint8)
            _outline(img, m, (255, 255, 0), 1)
            cv2.putText(
                img,
                f"{name} f{f}",
                (6, 16),
                cv2.FONT_HERSHEY_SIMPLEX,
                0.45,
                (255, 255, 255),
                1,
                cv2.LINE_AA,
            )
            tiles.append(img)
        rows.append(np.hstack(tiles))
    w = min(r.shape[1] for r in rows)
    grid = np.vstack([r[:, :w] for r in rows])
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), cv2.cvtColor(grid, cv2.COLOR_RGB2BGR))
