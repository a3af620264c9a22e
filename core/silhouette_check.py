"""Check a fitted body against a camera it was not fitted with: silhouette overlap (IoU).

With no ground truth for the joints (real video), the honest measure of a fit is how
well the fitted body, projected into a held-out camera, covers the person's foreground
there.  The body is rendered exactly (:func:`core.model_render.render_parts`: each
metaball's rendered ellipsoid, :attr:`core.metaballs.Metaballs.visible`, ray-cast per
pixel) and compared with the foreground mask of that camera (:mod:`core.background`).

Frames: world Z up, metres; cameras as in :mod:`core.camera` (pixels, OpenCV frame).
"""

from __future__ import annotations

import numpy as np

from .camera import Camera
from .contour_obs import body_ellipsoids
from .metaballs import Metaballs
from .model_render import camera_rays, render_parts
from .skeleton import Skeleton


def body_masks(
    skel: Skeleton,
    s: np.ndarray,
    balls: Metaballs,
    theta: np.ndarray,
    root_xyz: np.ndarray,
    camera: Camera,
    rays: np.ndarray | None = None,
) -> np.ndarray:
    """Silhouettes of the body in ``camera`` for F poses.

    Parameters
    ----------
    skel, s, balls
        The subject's skeleton, bone scales (G,) and metaballs.
    theta : ndarray, shape (F, n)
        Joint angles per frame, radians.
    root_xyz : ndarray, shape (F, 3)
        Root (pelvis) position per frame, world metres.
    camera : Camera
    rays : ndarray, shape (H, W, 3), optional
        Cached viewing rays of ``camera`` (:func:`core.model_render.camera_rays`).

    Returns
    -------
    ndarray, shape (F, H, W), bool
        True where the body covers the pixel.  A frame whose pose is not finite gives
        an empty mask.
    """
    theta = np.atleast_2d(np.asarray(theta, float))
    root_xyz = np.atleast_2d(np.asarray(root_xyz, float))
    if len(theta) != len(root_xyz):
        raise ValueError(f"{len(theta)} frames of angles but {len(root_xyz)} root positions")
    w, h = camera.size
    rays = camera_rays(camera) if rays is None else rays
    out = np.zeros((len(theta), h, w), bool)
    n_parts = len(skel.bone_names)
    for f in range(len(theta)):
        if not (np.all(np.isfinite(theta[f])) and np.all(np.isfinite(root_xyz[f]))):
            continue
        centers, axes, radii, part = body_ellipsoids(skel, theta[f], root_xyz[f], s, balls)
        out[f] = render_parts(camera, centers, axes, radii, part, n_parts, rays=rays).mask
    return out


def mask_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Intersection over union of boolean masks, per frame.

    Parameters
    ----------
    a, b : ndarray, shape (F, H, W) or (H, W), bool

    Returns
    -------
    ndarray, shape (F,) (or a 0-d array for single masks)
        ``|a ∧ b| / |a ∨ b|``; NaN where both masks are empty.
    """
    a = np.asarray(a, bool)
    b = np.asarray(b, bool)
    if a.shape != b.shape:
        raise ValueError(f"masks of shapes {a.shape} and {b.shape} cannot be compared")
    axes = (-2, -1)
    inter = np.sum(a & b, axis=axes).astype(float)
    union = np.sum(a | b, axis=axes).astype(float)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(union > 0, inter / np.maximum(union, 1.0), np.nan)


def shift_iou(
    model: np.ndarray, image: np.ndarray, max_shift_px: int = 16
) -> tuple[np.ndarray, np.ndarray]:
    """IoU after the one image shift that best aligns all frames' masks.

    A constant offset of the held-out camera's calibration (or a systematic click
    bias) shifts every projected silhouette alike; fitting one 2-D shift over all
    frames separates that from per-frame pose errors.  The shift maximises the pooled
    IoU ``Σ|a ∧ b| / Σ|a ∨ b|`` over all integer shifts within ``max_shift_px``
    (cross-correlation by FFT, zero padding).

    Parameters
    ----------
    model, image : ndarray, shape (F, H, W), bool
        Projected body and observed foreground per frame.
    max_shift_px : int

    Returns
    -------
    shift : ndarray, shape (2,)
        ``(du, dv)`` pixels by which the model masks are moved.
    iou : ndarray, shape (F,)
        Per-frame IoU of the shifted model masks (NaN where both are empty).
    """
    a = np.asarray(model, bool)
    b = np.asarray(image, bool)
    if a.shape != b.shape or a.ndim != 3:
        raise ValueError(f"masks of shapes {a.shape} and {b.shape} cannot be compared")
    _, h, w = a.shape
    r = int(max_shift_px)
    shape = (h + 2 * r, w + 2 * r)
    fa = np.fft.rfft2(a.astype(np.float32), shape)
    fb = np.fft.rfft2(b.astype(np.float32), shape)
    corr = np.fft.irfft2(np.sum(fb * np.conj(fa), axis=0), shape)  # Σ_x a(x) b(x + s)
    dv = np.r_[0 : r + 1, -r:0]
    du = np.r_[0 : r + 1, -r:0]
    inter = corr[np.ix_(dv % shape[0], du % shape[1])]
    union = a.sum() + b.sum() - inter
    k = np.unravel_index(np.argmax(inter / np.maximum(union, 1.0)), inter.shape)
    shift = np.array([du[k[1]], dv[k[0]]])
    moved = np.zeros_like(a)
    su, sv = shift
    moved[:, max(sv, 0) : h + min(sv, 0), max(su, 0) : w + min(su, 0)] = a[
        :, max(-sv, 0) : h + min(-sv, 0), max(-su, 0) : w + min(-su, 0)
    ]
    return shift, mask_iou(moved, b)
