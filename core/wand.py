"""Reference-bar (wand) target measurement in images.

Each wand image should show two bright targets on a dark background.  A target's
image position is the intensity-weighted centroid of its blob (background level
subtracted), which is sub-pixel accurate.  An image with fewer or more than two blobs
(a target missing, occluded, merged with the other, or a stray light) gives NaN and is
counted in :class:`WandDetections`.

End labels: the two targets are usually identical, so A/B is fixed per image by a
deterministic rule (continuity with the previous frame when the bar moved little,
otherwise left-to-right); the cross-camera consistency of the labels is established
by epipolar geometry in :mod:`core.orientation` (``relabel``), and the bar-length
condition is symmetric in A and B.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass
class WandDetections:
    """Target image points of a wand sequence.

    Attributes
    ----------
    uv : ndarray, shape (F, C, 2, 2)
        Targets A, B in every frame and camera, pixels (NaN where dropped).
    n_blobs : ndarray, shape (F, C), int
        Blobs found per image.
    """

    uv: np.ndarray
    n_blobs: np.ndarray

    @property
    def dropped(self) -> np.ndarray:
        """(F, C) bool: images without exactly two targets."""
        return self.n_blobs != 2

    def summary(self) -> str:
        F, C = self.n_blobs.shape
        miss = int(np.sum(self.n_blobs < 2))
        extra = int(np.sum(self.n_blobs > 2))
        return (
            f"{F} frames x {C} cameras: {F * C - miss - extra} images with both "
            f"targets, {miss} dropped (target missing or merged), {extra} dropped "
            f"(more than two blobs)"
        )


def detect_targets(
    img: np.ndarray, threshold: float | None = None, min_area: int = 3
) -> np.ndarray:
    """Bright blobs of one grey image -> intensity-weighted centroids (K, 2), pixels.

    Parameters
    ----------
    img : ndarray, shape (H, W)
        Grey image.
    threshold : float, optional
        Grey level separating targets from the background; default halfway between the
        background (median) and the brightest pixel.
    min_area : int
        Smaller blobs are noise.

    Returns
    -------
    ndarray, shape (K, 2)
        ``(u, v)`` of each blob, sorted by ``u``; weights are the grey levels above the
        background inside the blob grown by one pixel.
    """
    img = np.asarray(img, dtype=np.float64)
    bg = float(np.median(img))
    peak = float(img.max())
    if peak - bg < 10:
        return np.zeros((0, 2))
    thr = threshold if threshold is not None else bg + 0.5 * (peak - bg)
    mask = (img > thr).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    keep = np.flatnonzero(stats[1:, cv2.CC_STAT_AREA] >= min_area) + 1
    if keep.size == 0:
        return np.zeros((0, 2))
    # grow each blob by one pixel so the faint rim contributes to the centroid
    grown = cv2.dilate(labels.astype(np.float32), np.ones((3, 3), np.uint8)).astype(int)
    grown = np.where(labels > 0, labels, grown)
    w = np.clip(img - bg, 0.0, None)
    vv, uu = np.indices(img.shape)
    lab = grown.ravel()
    sw = np.bincount(lab, w.ravel(), minlength=n)
    su = np.bincount(lab, (w * uu).ravel(), minlength=n)
    sv = np.bincount(lab, (w * vv).ravel(), minlength=n)
    uv = np.stack([su[keep] / sw[keep], sv[keep] / sw[keep]], axis=1)
    return uv[np.argsort(uv[:, 0])]


def label_sequence(points: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Per-camera A/B labels of one camera's sequence of blob lists.

    ``points[i]`` is (K_i, 2).  Returns ``uv`` (F, 2, 2) (NaN unless K_i == 2) and the
    blob counts (F,).  When the bar moved less than a quarter of its image length since
    the last good frame, the labels follow continuity; otherwise left-to-right.
    """
    F = len(points)
    uv = np.full((F, 2, 2), np.nan)
    counts = np.array([len(p) for p in points])
    prev = None
    for i, p in enumerate(points):  # sequential by nature: each frame follows the last
        if len(p) != 2:
            continue
        cur = p
        if prev is not None:
            sep = np.linalg.norm(prev[0] - prev[1])
            d_same = np.linalg.norm(cur - prev, axis=1).max()
            d_swap = np.linalg.norm(cur[::-1] - prev, axis=1).max()
            if min(d_same, d_swap) < 0.25 * sep and d_swap < d_same:
                cur = cur[::-1]
        uv[i] = cur
        prev = cur
    return uv, counts


def detect_sequence(images, progress=None) -> WandDetections:
    """Targets of a whole wand sequence.

    Parameters
    ----------
    images : callable
        ``images(cam_index, frame) -> grey image``; with attributes ``n_frames`` and
        ``n_cameras``, or pass a :class:`core.scene.Scene`-like adapter (see
        :func:`core.calibrate.wand_images`).
    """
    F, C = images.n_frames, images.n_cameras
    uv = np.full((F, C, 2, 2), np.nan)
    counts = np.zeros((F, C), dtype=int)
    for c in range(C):  # images are read one by one anyway
        pts = []
        for f in range(F):
            pts.append(detect_targets(images(c, f)))
            if progress is not None:
                progress.update(c * F + f + 1, C * F, f"wand targets: camera {c + 1}/{C}")
        uv[:, c], counts[:, c] = label_sequence(pts)
    return WandDetections(uv=uv, n_blobs=counts)
