"""Per-camera background model and foreground masks (SPEC.md stage 6).

The background of each camera is a per-pixel colour with a per-pixel noise level,
estimated from frames without the person when there are some, or else from the take
itself: the start is each pixel's *temporal mode* — the colour cluster (three adjacent
grey-level bins of 8) that the most frames share — and it is refined iteratively:
pixels classified as foreground in a frame are left out of that pixel's median in the
next round.  The mode, unlike a median, finds the backdrop where the person covers a
pixel in most frames but with changing colours (textured clothing moving past): the
backdrop returns to one colour, the person's colours scatter.  The noise level comes
from the frames close to the background colour only (:func:`_inlier_sigma`), so that
the person's frames do not inflate it.  On the studio's ``orthogonal3`` rig, where the
walker comes straight at the frontal camera and the dancers turn on the spot in front
of it, that camera's foreground IoU against the truth went from 0.21 / 0.66 / 0.61
(temporal median and the median absolute deviation over all frames) to 0.95 / 0.95 /
0.96 (walk / dance / pirouette), the other cameras unchanged at 0.95–0.96.

A pixel is foreground when its colour differs from the background by more than
``threshold`` noise levels *and* the difference is not a shadow: a cast shadow
darkens the background colour (brightness ratio ``alpha`` in ``shadow_range``) without
changing its chromaticity (Horprasert et al.'s brightness / chromaticity distortion)
and, unlike dark texture on the person, dims it smoothly (the brightness ratio is
locally uniform).
The mask is then cleaned by a morphological opening and closing, small holes are
filled (large ones are gaps between limbs), and connected components smaller than
``min_area_frac`` of the largest are dropped.

Images are ``(H, W, 3)`` uint8 RGB (or grey ``(H, W)``), pixel coordinates as in
:mod:`core.camera`.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import cv2
import numpy as np

from .errors import InputError
from .nan_median import nanmedian


@dataclass
class BackgroundModel:
    """Background of one camera.

    Attributes
    ----------
    colour : ndarray, shape (H, W, 3), float32
        Background colour, grey levels 0..255.
    sigma : ndarray, shape (H, W), float32
        Noise level of the colour difference per pixel, grey levels (≥ ``min_sigma``).
    known : ndarray, shape (H, W), bool
        Pixels whose background was seen often enough to be trusted; pixels that were
        covered in (nearly) every frame stay unknown and are never called foreground
        by colour alone.
    """

    colour: np.ndarray
    sigma: np.ndarray
    known: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return self.colour.shape[:2]

    def difference(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Normalised colour distance and brightness ratio of ``image`` against the model.

        Returns
        -------
        dist : ndarray (H, W) float32
            ``|I - B| / sigma`` (noise levels).
        chroma : ndarray (H, W) float32
            Chromaticity distortion ``|I - alpha B| / sigma`` (noise levels).
        alpha : ndarray (H, W) float32
            Brightness ratio ``<I, B> / <B, B>``.
        """
        img = _as_rgb(image).astype(np.float32)
        b = self.colour
        diff = img - b
        dist = np.sqrt(np.einsum("hwc,hwc->hw", diff, diff)) / self.sigma
        bb = np.einsum("hwc,hwc->hw", b, b) + 1e-3
        alpha = np.einsum("hwc,hwc->hw", img, b) / bb
        cd = img - alpha[..., None] * b
        chroma = np.sqrt(np.einsum("hwc,hwc->hw", cd, cd)) / self.sigma
        return dist, chroma, alpha

    def foreground(
        self,
        image: np.ndarray,
        threshold: float = 5.0,
        shadow_range: tuple[float, float] = (0.45, 0.95),
        shadow_chroma: float = 4.0,
        shadow_texture: float = 0.04,
        min_area_frac: float = 0.1,
        clean_px: int = 1,
    ) -> np.ndarray:
        """Foreground mask of one image, ``(H, W)`` bool (see the module docstring)."""
        if image.shape[:2] != self.shape:
            raise InputError(
                f"image of size {image.shape[1]}x{image.shape[0]} does not match the "
                f"background model {self.shape[1]}x{self.shape[0]}"
            )
        dist, chroma, alpha = self.difference(image)
        fg = dist > threshold
        shadow = (alpha > shadow_range[0]) & (alpha < shadow_range[1]) & (chroma < shadow_chroma)
        # A cast shadow dims the background smoothly; dark texture on the person (which
        # also looks like "darker background" on a grey backdrop) makes alpha vary
        # from pixel to pixel.  Keep as shadow only where alpha is locally uniform.
        a = np.where(np.isfinite(alpha), alpha, 0.0).astype(np.float32)
        mean = cv2.blur(a, (5, 5))
        var = np.maximum(cv2.blur(a * a, (5, 5)) - mean * mean, 0.0)
        shadow &= np.sqrt(var) < shadow_texture
        fg &= ~shadow
        fg &= self.known
        return clean_mask(fg, clean_px=clean_px, min_area_frac=min_area_frac)


def _as_rgb(image: np.ndarray) -> np.ndarray:
    if image.ndim == 2:
        return np.repeat(image[..., None], 3, axis=2)
    return image


def clean_mask(
    mask: np.ndarray, clean_px: int = 1, min_area_frac: float = 0.1, max_hole_frac: float = 0.005
) -> np.ndarray:
    """Open, close, fill small holes and drop small components of a boolean mask (H, W).

    Holes smaller than ``max_hole_frac`` of their component's area are texture that
    matched the background and are filled; larger ones are real gaps (between the legs,
    between an arm and the torso) and stay.
    """
    m = mask.astype(np.uint8)
    if clean_px > 0:
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * clean_px + 1, 2 * clean_px + 1))
        m = cv2.morphologyEx(m, cv2.MORPH_OPEN, k)
        m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, k)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    if n <= 1:
        return np.zeros(mask.shape, bool)
    areas = stats[1:, cv2.CC_STAT_AREA]
    keep = np.zeros(n, bool)
    keep[1:] = areas >= min_area_frac * areas.max()
    m = keep[labels].astype(np.uint8)
    contours, hierarchy = cv2.findContours(m, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    if hierarchy is not None:
        for i, c in enumerate(contours):
            parent = hierarchy[0][i][3]
            if parent < 0:
                continue
            if cv2.contourArea(c) < max_hole_frac * cv2.contourArea(contours[parent]):
                cv2.drawContours(m, contours, i, 1, thickness=cv2.FILLED)
    return m.astype(bool)


def fit_background(
    frames: np.ndarray,
    empty: np.ndarray | None = None,
    iterations: int = 2,
    threshold: float = 5.0,
    min_sigma: float = 2.0,
    max_frames: int = 40,
    min_known_frac: float = 0.05,
    min_mode_frames: int = 3,
    exclude: np.ndarray | None = None,
) -> BackgroundModel:
    """Estimate a camera's background.

    Parameters
    ----------
    frames : ndarray, shape (N, H, W, 3) or (N, H, W), uint8
        Frames of the take (the person may be present).
    empty : ndarray, shape (M, H, W, 3), optional
        Frames without the person.  When given they alone define the background.
    iterations : int
        Refinement rounds of the masked temporal median.
    threshold : float
        Foreground threshold in noise levels used during refinement.
    min_sigma : float
        Floor of the per-pixel noise level, grey levels.
    max_frames : int
        At most this many frames (evenly spaced) enter the medians, for speed.
    min_known_frac : float
        A pixel is *known* when it was background in at least this fraction of frames
        in the last refinement round, ...
    min_mode_frames : int
        ... or when its temporal mode is shared by at least this many frames (then the
        mode's colour stands; a person covering the pixel in nearly every frame leaves
        the refinement too few background frames, but the mode still has them).
    exclude : ndarray, shape (N, H, W), bool, optional
        Pixels known to show the person in each frame (e.g. the fitted body projected
        and dilated): they never enter the medians.  This is what frees the background
        where a person stood still for more than half of the take.

    Returns
    -------
    BackgroundModel
    """
    src = empty if empty is not None and len(empty) > 0 else frames
    src = np.asarray(src)
    if src.ndim not in (3, 4) or len(src) == 0:
        raise InputError("background needs at least one frame of shape (H, W[, 3])")
    if src.ndim == 3:
        src = np.repeat(src[..., None], 3, axis=3)
    use_empty = empty is not None and len(empty) > 0
    if exclude is not None and not use_empty:
        exclude = np.asarray(exclude, bool)
        if exclude.shape != src.shape[:3]:
            raise InputError(
                f"exclude masks of shape {exclude.shape} do not match the frames {src.shape[:3]}"
            )
    else:
        exclude = None
    if len(src) > max_frames:
        pick = np.linspace(0, len(src) - 1, max_frames).round().astype(int)
        src = src[pick]
        exclude = None if exclude is None else exclude[pick]
    stack = src.astype(np.float32)
    if use_empty:
        colour = np.median(stack, axis=0)
        return BackgroundModel(
            colour, _inlier_sigma(stack, colour, min_sigma), np.ones(colour.shape[:2], bool)
        )
    mode, mode_n = _mode_colour(stack)
    if exclude is None:
        colour = mode
        sigma = _inlier_sigma(stack, colour, min_sigma)
    else:
        colour = nanmedian(np.where(exclude[..., None], np.nan, stack), axis=0)
        colour = np.where(np.isfinite(colour), colour, mode)
        sigma = _inlier_sigma(stack, colour, min_sigma, weights=~exclude)
    known = np.ones(colour.shape[:2], bool)
    for _ in range(iterations):
        model = BackgroundModel(colour, sigma, np.ones_like(known))
        bg = np.empty(stack.shape[:3], bool)
        for i, img in enumerate(src):
            # dilated foreground so that soft edges stay out of the median
            fg = model.foreground(img, threshold=threshold, min_area_frac=0.0, clean_px=1)
            bg[i] = ~cv2.dilate(fg.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
            if exclude is not None:
                bg[i] &= ~exclude[i]
        masked = np.where(bg[..., None], stack, np.nan)
        counts = bg.sum(axis=0)
        known = counts >= max(1, int(np.ceil(min_known_frac * len(src))))
        new = nanmedian(masked[:, known], axis=0)
        colour = colour.copy()
        colour[known] = new
        sigma = _inlier_sigma(stack, colour, min_sigma, weights=bg)
    by_mode = ~known & (mode_n >= min_mode_frames)
    if exclude is not None:  # the person's pixels' mode is not the background
        by_mode &= np.sum(~exclude, axis=0) >= min_mode_frames
    colour[by_mode] = mode[by_mode]
    known |= by_mode
    return BackgroundModel(colour.astype(np.float32), sigma.astype(np.float32), known)


def _mode_colour(stack: np.ndarray, bins: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """Temporal mode of every pixel: colour (H, W, 3) and frame count (H, W).

    Each frame's grey level falls into one of ``bins`` bins; the three adjacent bins
    holding the most frames win, and the colour is the median of those frames.
    ``stack`` (N, H, W, 3) float32.
    """
    N, H, W, _ = stack.shape
    b = np.clip((stack.mean(axis=3) * (bins / 256.0)).astype(np.int64), 0, bins - 1)
    idx = (np.arange(H * W, dtype=np.int64).reshape(1, H, W) * bins + b).ravel()
    cnt = np.bincount(idx, minlength=H * W * bins).reshape(H, W, bins)
    near = cnt.copy()
    near[..., 1:] += cnt[..., :-1]
    near[..., :-1] += cnt[..., 1:]
    best = np.argmax(near, axis=2)
    pick = np.abs(b - best[None]) <= 1
    colour = nanmedian(np.where(pick[..., None], stack, np.nan), axis=0)
    return colour, np.take_along_axis(near, best[..., None], axis=2)[..., 0]


def _inlier_sigma(stack, colour, min_sigma, weights=None, k: float = 4.0, min_tol: float = 12.0):
    """Per-pixel noise level (H, W) of the colour distance, from background frames only.

    The camera-wide level ``g`` (the median distance over all pixels and frames —
    mostly background — scaled to σ) sets a tolerance ``max(k g, min_tol)``; each
    pixel's level is the robust spread (median / 1.54: the median of the norm of
    3-channel Gaussian noise is 1.54 σ) of its frames within that tolerance of the
    background colour (``weights`` (N, H, W) bool: frames allowed), ``g`` where fewer
    than 3 are.  Frames showing the person lie outside the tolerance and do not inflate
    the level, as they did with a median absolute deviation over every frame.
    """
    d = np.sqrt(((stack - colour[None]) ** 2).sum(axis=-1))  # (N, H, W)
    if weights is not None:
        d = np.where(weights, d, np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        g = float(np.nanmedian(d)) / 1.54
    g = max(g if np.isfinite(g) else min_sigma, min_sigma)
    inl = np.where(d < max(k * g, min_tol), d, np.nan)
    med = nanmedian(inl, axis=0)
    enough = np.sum(np.isfinite(inl), axis=0) >= 3
    sigma = np.where(enough & np.isfinite(med), med / 1.54, g)
    # a little spatial pooling keeps single noisy estimates from making holes
    sigma = cv2.blur(sigma.astype(np.float32), (5, 5))
    return np.maximum(sigma, min_sigma).astype(np.float32)


def with_reference(
    model: BackgroundModel,
    frames: np.ndarray,
    reference: np.ndarray,
    tol: float = 20.0,
    min_support: float = 0.1,
    min_diff: float = 25.0,
    sigma_floor: float = 4.0,
    open_px: int = 2,
) -> BackgroundModel:
    """Repair a temporal-median background with an image of the empty scene.

    A person who holds one pose for more than half of the take burns into the median
    (their torso then never shows as foreground).  Where ``reference`` (the empty scene
    from the same camera, e.g. a calibration photo; brightness matched per channel by
    the median ratio) differs from the model by more than ``min_diff`` grey levels in a
    compact region (thin edges from a sub-pixel misregistration are removed by an
    opening of ``open_px``), *and* at least ``min_support`` of the frames agree with the
    reference there (within ``tol`` grey levels — so a person present only in the
    reference is not copied in), the reference colour replaces the median and the noise
    level is raised to at least ``sigma_floor`` (two exposures differ).

    Parameters
    ----------
    model : BackgroundModel
        From :func:`fit_background` on ``frames``.
    frames : ndarray, shape (N, H, W, 3) or (N, H, W), uint8
    reference : ndarray, shape (H, W, 3) or (H, W), uint8
        The empty scene, registered to the frames.

    Returns
    -------
    BackgroundModel
        A repaired copy (``known`` set where the reference was taken).
    """
    ref = _as_rgb(np.asarray(reference)).astype(np.float32)
    if ref.shape[:2] != model.shape:
        raise InputError(
            f"reference image of size {ref.shape[1]}x{ref.shape[0]} does not "
            f"match the background model {model.shape[1]}x{model.shape[0]}"
        )
    frames = np.asarray(frames)
    if frames.ndim == 3:
        frames = np.repeat(frames[..., None], 3, axis=3)
    gain = np.median(ref / (model.colour + 1.0), axis=(0, 1))
    ref = np.clip(ref / gain, 0.0, 255.0)
    diff = np.linalg.norm(ref - model.colour, axis=2) > min_diff
    if open_px > 0:
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * open_px + 1, 2 * open_px + 1))
        diff = cv2.morphologyEx(diff.astype(np.uint8), cv2.MORPH_OPEN, k).astype(bool)
    if not diff.any():
        return BackgroundModel(model.colour.copy(), model.sigma.copy(), model.known.copy())
    vv, uu = np.nonzero(diff)
    d = np.linalg.norm(frames[:, vv, uu].astype(np.float32) - ref[None, vv, uu], axis=2)
    take = np.mean(d < tol, axis=0) >= min_support
    colour, sigma, known = model.colour.copy(), model.sigma.copy(), model.known.copy()
    vv, uu = vv[take], uu[take]
    colour[vv, uu] = ref[vv, uu]
    sigma[vv, uu] = np.maximum(sigma[vv, uu], sigma_floor)
    known[vv, uu] = True
    return BackgroundModel(colour, sigma, known)
