"""Occluding contours of a foreground mask as smooth closed curves with tangents.

The second paper fits a 2-D deformable curve to each occluding contour to get a smooth,
differentiable curve with tangents.  We do the equivalent: the pixel boundary
(``cv2.findContours``) is resampled at uniform arc length and smoothed by a periodic
Gaussian — the minimiser of a membrane energy with a quadratic data term — whose
analytic derivative gives the tangent.  Both the outer boundaries and holes (e.g. the
gap between an arm and the torso) are contours; normals always point out of the
foreground.

Coordinates are image pixels (``u`` right, ``v`` down; pixel centres at integers).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.ndimage import gaussian_filter1d


@dataclass
class Contour:
    """One closed occluding contour.

    Attributes
    ----------
    uv : ndarray, shape (N, 2)
        Points along the smoothed curve at (about) ``spacing`` px intervals, pixels.
    tangent : ndarray, shape (N, 2)
        Unit tangents, in the direction of increasing index.
    normal : ndarray, shape (N, 2)
        Unit normals pointing out of the foreground.
    curvature : ndarray, shape (N,)
        Signed curvature, 1/px (positive where the foreground is convex).
    hole : bool
        True for the boundary of a hole inside the foreground.
    """

    uv: np.ndarray
    tangent: np.ndarray
    normal: np.ndarray
    curvature: np.ndarray
    hole: bool = False

    def __len__(self) -> int:
        return len(self.uv)


def _resample_closed(pts: np.ndarray, spacing: float) -> np.ndarray:
    closed = np.vstack([pts, pts[:1]])
    seg = np.linalg.norm(np.diff(closed, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    length = s[-1]
    n = max(8, int(round(length / spacing)))
    t = np.linspace(0.0, length, n, endpoint=False)
    return np.stack([np.interp(t, s, closed[:, 0]), np.interp(t, s, closed[:, 1])], axis=1)


def occluding_contours(
    mask: np.ndarray,
    spacing: float = 2.0,
    smooth_px: float = 3.0,
    min_length_px: float = 40.0,
    holes: bool = True,
) -> list[Contour]:
    """Extract the occluding contours of a foreground mask.

    Parameters
    ----------
    mask : ndarray, shape (H, W), bool
        Foreground.
    spacing : float
        Sampling interval along the curve, pixels.
    smooth_px : float
        Standard deviation of the periodic Gaussian smoothing, pixels of arc length.
    min_length_px : float
        Contours shorter than this are dropped (specks).
    holes : bool
        Include the boundaries of holes.

    Returns
    -------
    list of Contour
        Outer contours first, longest first.
    """
    m = np.ascontiguousarray(mask.astype(np.uint8))
    mode = cv2.RETR_CCOMP if holes else cv2.RETR_EXTERNAL
    raw, hierarchy = cv2.findContours(m, mode, cv2.CHAIN_APPROX_NONE)
    out: list[Contour] = []
    for i, c in enumerate(raw):
        pts = c[:, 0, :].astype(float)
        if len(pts) < 4:
            continue
        is_hole = bool(hierarchy is not None and hierarchy[0][i][3] >= 0)
        # Pixel-centre boundary: move half a pixel outwards later via the normal.
        uv = _resample_closed(pts, spacing)
        if len(uv) * spacing < min_length_px:
            continue
        sig = max(smooth_px / spacing, 1e-6)
        smooth = np.stack([gaussian_filter1d(uv[:, k], sig, mode="wrap") for k in (0, 1)], axis=1)
        # Re-parametrise the smooth curve by its own arc length (the pixel staircase is
        # longer than the curve and would bias the derivatives), then differentiate.
        uv = _resample_closed(smooth, spacing)
        x, y = uv[:, 0], uv[:, 1]
        # central differences (sampled Gaussian-derivative kernels are biased at small σ)
        dx = 0.5 * (np.roll(x, -1) - np.roll(x, 1))
        dy = 0.5 * (np.roll(y, -1) - np.roll(y, 1))
        ddx = np.roll(x, -1) - 2.0 * x + np.roll(x, 1)
        ddy = np.roll(y, -1) - 2.0 * y + np.roll(y, 1)
        speed = np.hypot(dx, dy) + 1e-12
        tangent = np.stack([dx, dy], axis=1) / speed[:, None]
        # Orientation: signed area tells on which side the foreground lies.
        area = 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
        # In image coordinates (v down), a positive shoelace area means clockwise on
        # screen; the right-hand normal (ty, -tx) then points outwards for an outer contour.
        sign = 1.0 if area > 0 else -1.0
        if is_hole:
            sign = -sign
        normal = sign * np.stack([tangent[:, 1], -tangent[:, 0]], axis=1)
        acc = np.stack([ddx, ddy], axis=1)
        dt_ds = (acc - tangent * np.sum(tangent * acc, axis=1, keepdims=True)) / speed[:, None] ** 2
        # d(tangent)/ds points to the centre of curvature: convex (towards the
        # foreground, against the outward normal) counts positive.
        curvature = -np.sum(dt_ds * normal, axis=1)
        # findContours traces pixel centres on the boundary: the true edge lies half a
        # pixel further out.
        uv_s = np.stack([x, y], axis=1) + 0.5 * normal
        out.append(Contour(uv_s, tangent, normal, curvature, hole=is_hole))
    out.sort(key=lambda c: (c.hole, -len(c)))
    return out


def draw_contours(
    image: np.ndarray, contours: list[Contour], colour=(255, 64, 0), normals_every: int = 0
) -> np.ndarray:
    """Overlay contours (and optionally every n-th normal) on an RGB image copy."""
    out = image.copy() if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2RGB)
    for c in contours:
        pts = np.round(c.uv * 16).astype(np.int32)
        cv2.polylines(out, [pts], True, colour, 1, cv2.LINE_AA, shift=4)
        if normals_every:
            for p, n in zip(c.uv[::normals_every], c.normal[::normals_every], strict=True):
                q = p + 8 * n
                cv2.line(
                    out,
                    tuple(np.round(p).astype(int)),
                    tuple(np.round(q).astype(int)),
                    (0, 200, 255),
                    1,
                    cv2.LINE_AA,
                )
    return out
