"""Key templates: drift-free re-anchoring of temporal matches.

Frame-to-frame matching (template at frame i, search at i+1) accumulates the small
errors of every step: the trajectory random-walks away from its material point.  A
key template per point and camera stops that walk: after the temporal match into
frame i+1, the point is matched once more from its *key* template (the patch where the
point was first measured in that camera), started at the temporal match with the key's
affine carried along (the temporal affines composed since the key).  The key is
refreshed — set to the current measurement — only when that key match fails or moves
too far from the temporal match (the appearance changed beyond the affine model), or
when the carried affine says the patch is strongly distorted.

Shapes: P points, C cameras.  Positions in pixels; an affine maps template-pixel
offsets to search-image offsets (as :attr:`core.lsm.LSMResult.affine`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .lsm import ImageStack, match


@dataclass
class KeyTemplates:
    """Key template of every (point, camera) pair.

    Attributes
    ----------
    f : ndarray, shape (P, C), int
        Frame of the key template, -1 where none.
    uv : ndarray, shape (P, C, 2)
        Key position in that frame, pixels.
    affine : ndarray, shape (P, C, 2, 2)
        Affine from the key patch to the last measurement of the point in that camera.
    """

    f: np.ndarray
    uv: np.ndarray
    affine: np.ndarray

    @classmethod
    def start(cls, uv: np.ndarray, frame: int) -> KeyTemplates:
        """Keys at ``uv`` (P, C, 2) of frame ``frame`` where finite."""
        uv = np.asarray(uv, float)
        seen = np.all(np.isfinite(uv), axis=2)
        aff = np.broadcast_to(np.eye(2), uv.shape[:2] + (2, 2)).copy()
        return cls(np.where(seen, frame, -1), uv.copy(), aff)

    def append(self, other: KeyTemplates) -> None:
        self.f = np.concatenate([self.f, other.f])
        self.uv = np.concatenate([self.uv, other.uv])
        self.affine = np.concatenate([self.affine, other.affine])

    def frames(self) -> set[int]:
        """Frames whose images some key still needs."""
        return set(np.unique(self.f[self.f >= 0]).tolist())

    def reset(self, pi: np.ndarray, ci: np.ndarray, uv: np.ndarray, frame: int) -> None:
        """Make the measurements ``uv`` (K, 2) of pairs ``(pi, ci)`` (K,) at ``frame``
        their keys."""
        self.f[pi, ci] = frame
        self.uv[pi, ci] = uv
        self.affine[pi, ci] = np.eye(2)


def distortion(affine: np.ndarray) -> np.ndarray:
    """Largest |log| of the singular values of affines (..., 2, 2): 0 for a rotation,
    log 1.25 for a 25 % stretch; inf where singular or not finite."""
    a = np.where(np.isfinite(affine), affine, 0.0)
    s = np.linalg.svd(a, compute_uv=False)
    with np.errstate(divide="ignore"):
        out = np.max(np.abs(np.log(s)), axis=-1)
    return np.where(np.all(np.isfinite(affine), axis=(-2, -1)), out, np.inf)


def reanchor(
    keys: KeyTemplates,
    stacks: dict,
    search: ImageStack,
    pi: np.ndarray,
    ci: np.ndarray,
    uv_t: np.ndarray,
    affine_t: np.ndarray,
    *,
    half: int = 6,
    max_px: float = 1.0,
    max_distortion: float = np.log(1.5),
    weight_sigma: float | None = 4.0,
    max_sigma_px: float = 0.2,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Match temporal matches again from their key templates.

    Parameters
    ----------
    keys : KeyTemplates
    stacks : dict int -> ImageStack
        Images of every key frame in use, camera order.
    search : ImageStack
        Images of the new frame, camera order.
    pi, ci : ndarray, shape (K,), int
        Point and camera of each temporal match.
    uv_t : ndarray, shape (K, 2)
        Temporal matches in the new frame, pixels.
    affine_t : ndarray, shape (K, 2, 2)
        Their affines from the last measurement to the new frame.
    max_px : float
        Largest distance between the key match and the temporal match, pixels.
    max_distortion : float
        Keys whose carried affine is more distorted (:func:`distortion`) are not used.

    Returns
    -------
    uv : ndarray, shape (K, 2)
        Key matches where ``ok``, else the temporal matches, pixels.
    affine : ndarray, shape (K, 2, 2)
        Affine from the key patch to the new frame (meaningful where ``ok``).
    ok : ndarray, shape (K,), bool
        The key match converged within ``max_px`` of the temporal match; the other
        pairs should have their keys reset to the new measurement.
    """
    uv_t = np.asarray(uv_t, float)
    aff = affine_t @ keys.affine[pi, ci]
    kf = keys.f[pi, ci]
    use = (kf >= 0) & (distortion(aff) < max_distortion) & np.all(np.isfinite(uv_t), axis=1)
    out_uv, out_aff, ok = uv_t.copy(), aff, np.zeros(len(pi), bool)
    k = np.flatnonzero(use)
    if len(k) == 0:
        return out_uv, out_aff, ok
    fr = np.unique(kf[k])
    c = search.shape[0]
    tstack = (
        stacks[int(fr[0])]
        if len(fr) == 1
        else ImageStack(np.concatenate([stacks[int(f)].images for f in fr]))
    )
    tidx = np.searchsorted(fr, kf[k]) * c + ci[k]
    r = match(
        tstack,
        search,
        keys.uv[pi[k], ci[k]],
        uv_t[k],
        half=half,
        affine=aff[k],
        template_index=tidx,
        search_index=ci[k],
        max_shift_px=max_px,
        weight_sigma=weight_sigma,
        max_sigma_px=max_sigma_px,
    )
    good = r.ok & (np.linalg.norm(r.uv - uv_t[k], axis=1) < max_px)
    out_uv[k[good]] = r.uv[good]
    out_aff[k[good]] = r.affine[good]
    ok[k[good]] = True
    return out_uv, out_aff, ok
