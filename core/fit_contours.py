"""Occluding contours as an observation type of the per-frame weighted least squares.

Issue 7, item 6: the sequence fit (:mod:`core.fit`, :mod:`core.fitting`) can use texture
points, silhouette contours, or both.  A :class:`ContourFrame` holds one frame's image
contours (from the scene's foreground, :func:`scene_contours`) and plugs into
:class:`core.fitting.Observations` (``contours``).  Inside the fit it acts like the
attractor points' re-weighting (IRLS):

* at the start of every re-weighting round (:meth:`ContourFrame.freeze`) the body at the
  current state is rendered into every camera, its visible rim paired with the image
  contours for the parts that selected that camera (visibility ≥ 0.2, observability
  ranking, and a view across the kept ones where those all look from one side,
  ``ContourSettings.wide_view_deg``; the public functions of :mod:`core.model_render`,
  :mod:`core.model_contours`, :mod:`core.camera_selection`, :mod:`core.contour_match`, as in
  :func:`core.contour_obs.contour_observations`), and the Huber weights are fixed;
* within the round each pair ``i`` is one observation equation (pixels)

      r_i = n_i · (z_i − proj_c(x_i(θ, root, s, radii, centres))),

  ``z_i`` the image contour point, ``n_i`` its outward image normal, and ``x_i`` the rim
  point held fixed in its metaball's unit-sphere frame
  (``x = c_e + R_e (v_e ∘ l_e ∘ p)``, ``v_e`` its ``visible_scale``),
  so that the residual is a smooth function of every unknown and its analytic Jacobian
  (:func:`contour_block`) is exact;
* each row is divided by the a-priori σ (``ContourSettings.sigma_px``, pixels), which
  weights it against the other observation types by ``p_i / p_j = σ_j² / σ_i²``
  (eq. 12), and multiplied by the square root of its Huber weight (knee ``huber_px``).

The cameras each part used are kept per frame (:attr:`ContourFrame.selection`,
:meth:`ContourFrame.cameras_used`) for the fitted state's quality.

The pairing and the residual block live in :mod:`core.contour_pairs`
(:func:`match_frame`, :func:`contour_block`), the options in :mod:`core.contour_settings`
(:class:`ContourSettings`); both are re-exported here.

Frames: world Z up, metres; image pixels as in :mod:`core.camera`; angles radians.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera import Camera
from .camera_selection import Selection
from .contour_obs import containment_observations, contour_mask, silhouette_field
from .contour_pairs import (
    ContourPairs,
    _empty_pairs,
    contour_block,
    match_frame,
    outer_rim,  # noqa: F401  (re-exported)
)
from .contour_settings import ContourSettings
from .contours import Contour, occluding_contours
from .metaballs import Metaballs
from .model_render import camera_rays
from .skeleton import Skeleton


def containment_parts(
    counts: np.ndarray, with_points: bool, min_part_points: int, cfg: ContourSettings
) -> np.ndarray:
    """The parts the silhouette containment holds in one frame, shape (P,) bool.

    ``counts`` (P,) are the texture points near each part.  In a frame with points the
    term holds the parts with fewer than ``min_part_points`` of them — a limb the points
    miss, which one view's contours cannot place in depth and which otherwise follows
    its prediction — or every part with ``cfg.containment_textured``.  In a frame with
    contours alone it holds none: there the silhouette limb search places the limbs
    (skin walk, line3, σ 3 px on every part: MPJPE 29.0 -> 37.4 mm).
    """
    counts = np.asarray(counts)
    if not with_points:
        return np.zeros(len(counts), bool)
    return (counts < min_part_points) | bool(cfg.containment_textured)


def _huber_sqrt(r: np.ndarray, k: float) -> np.ndarray:
    a = np.abs(r)
    return np.where(a <= k, 1.0, np.sqrt(k / np.maximum(a, 1e-300)))


class ContourFrame:
    """One frame's contour observations for :class:`core.fitting.Observations`.

    Parameters
    ----------
    cameras : list (C) of Camera
    contours : list (C) of list of Contour — the frame's image occluding contours
    settings : ContourSettings
    rays : list (C) of (H, W, 3) cached viewing rays, optional (shared between frames)
    theta_rate : (n,) predicted change of θ per frame, optional (observability ranking)

    Attributes
    ----------
    pairs : ContourPairs or None — the correspondences of the last :meth:`freeze`
    weights : (K,) row weights ``sqrt(huber) / σ`` of those pairs
    selection : Selection or None — the cameras each part used at the last freeze
    part_scale : (P,) factor on σ per body part, or None (1) — set by the sequence fit to
        ``textured_scale`` for the parts its texture points observe, so that the contours
        (whose metaball outline is not the body's) mainly place the parts the points miss
    containment_parts : (P,) bool of the parts the silhouette containment holds, or None
        (every part) — set by the sequence fit (:attr:`ContourSettings.containment_px`)
    """

    def __init__(
        self,
        cameras: list[Camera],
        contours: list[list[Contour]],
        settings: ContourSettings | None = None,
        rays: list[np.ndarray] | None = None,
        theta_rate: np.ndarray | None = None,
    ):
        if len(contours) != len(cameras):
            raise ValueError(f"{len(contours)} contour lists for {len(cameras)} cameras")
        self.cameras = list(cameras)
        self.contours = contours
        self.cfg = settings or ContourSettings()
        self.rays = rays
        self.theta_rate = theta_rate
        self.pairs: ContourPairs | None = None
        self.weights = np.zeros(0)
        self.selection: Selection | None = None
        self.part_scale: np.ndarray | None = None
        self.containment_parts: np.ndarray | None = None
        self._key: bytes | None = None
        self._masks: list | None = None
        self._grids: list | None = None
        self._fields: list | None = None

    @property
    def n_contour_points(self) -> int:
        return int(sum(len(c) for cam in self.contours for c in cam))

    def freeze(
        self, skel: Skeleton, balls: Metaballs, theta: np.ndarray, root: np.ndarray, s: np.ndarray
    ) -> None:
        """Pair the contours with the rim at this state and fix the Huber weights."""
        scale = np.zeros(0) if self.part_scale is None else self.part_scale
        key = b"".join(
            np.ascontiguousarray(a, float).tobytes()
            for a in (theta, root, s, balls.radii, balls.center0, scale)
        )
        if key == self._key and self.pairs is not None:
            return
        if self.n_contour_points == 0:
            self.pairs, self.selection = _empty_pairs(), None
        else:
            self.pairs, self.selection = match_frame(
                skel,
                balls,
                theta,
                root,
                s,
                self.cameras,
                self.contours,
                self.cfg,
                theta_rate=self.theta_rate,
                rays=self.rays,
            )
        r = contour_block(skel, balls, theta, root, s, self.cameras, self.pairs, shape=False)[0]
        sig = np.full(len(r), self.cfg.sigma_px)
        if self.part_scale is not None and len(r):
            sig = sig * np.asarray(self.part_scale, float)[self.pairs.bone]
        sig = sig * self.pairs.sigma_scale
        self.weights = _huber_sqrt(r / (sig / self.cfg.sigma_px), self.cfg.huber_px) / sig
        self._key = key

    def block(
        self,
        skel: Skeleton,
        balls: Metaballs,
        theta: np.ndarray,
        root: np.ndarray,
        s: np.ndarray,
        anc: np.ndarray | None = None,
        shape: bool = True,
    ):
        """Weighted residual rows ``(r, J_theta, J_root, J_s, J_radii, J_centers)`` of
        the frozen pairs (see :func:`contour_block`; every row times ``weights``)."""
        if self.pairs is None:
            self.freeze(skel, balls, theta, root, s)
        out = contour_block(skel, balls, theta, root, s, self.cameras, self.pairs, anc, shape)
        w = self.weights
        return tuple(None if a is None else (a * w if a.ndim == 1 else a * w[:, None]) for a in out)

    def containment_block(
        self, skel: Skeleton, balls: Metaballs, theta: np.ndarray, root: np.ndarray, s: np.ndarray
    ):
        """Silhouette-containment rows ``(r, J_theta, J_root)`` at a state, or None when
        the term is off (``containment_px`` 0), holds no part (:attr:`containment_parts`)
        or no camera has contours.

        :func:`core.contour_obs.containment_observations` (seven points inside every
        metaball, each a residual ``max(D − tol, 0)`` of the distance ``D`` outside the
        foreground, pixels), re-evaluated at every state — unlike the contour pairs it
        needs no correspondence, so its reach is the whole image — divided by
        ``containment_px`` and robust: above the Huber knee ``huber_px`` a residual
        ``r`` becomes ``sqrt(2 k r − k²)`` (its square is the Huber loss).
        """
        k_px = self.cfg.containment_px
        held = self.containment_parts
        if k_px <= 0 or (held is not None and not np.any(held)):
            return None
        use = [c for c, f in enumerate(self.fields()) if f is not None]
        if not use:
            return None
        co = containment_observations(
            skel,
            np.asarray(theta, float),
            np.asarray(root, float),
            s,
            balls,
            [self.cameras[c] for c in use],
            [self._fields[c] for c in use],
            tol_px=self.cfg.containment_tol_px,
            keep_parts=held,
        )
        k = self.cfg.huber_px
        r = co.residual
        big = r > k
        r_eff = np.where(big, np.sqrt(np.maximum(2.0 * k * r - k * k, 0.0)), r)
        d = np.where(big, k / np.maximum(r_eff, 1e-12), 1.0) / k_px
        return r_eff / k_px, co.J_theta * d[:, None], co.J_root * d[:, None]

    def fields(self) -> list:
        """:func:`core.contour_obs.silhouette_field` of every camera (None for a camera
        without contours); computed once."""
        if self._fields is None:
            self._fields = [
                silhouette_field(cons, cam.size) if cons else None
                for cons, cam in zip(self.contours, self.cameras, strict=True)
            ]
        return self._fields

    def masks(self) -> list:
        """Foreground (H, W) bool of every camera, enclosed by its contours (None for a
        camera without contours); computed once."""
        if self._masks is None:
            self._masks = [
                contour_mask(cons, cam.size) if cons else None
                for cons, cam in zip(self.contours, self.cameras, strict=True)
            ]
        return self._masks

    def grids(self) -> list:
        """:func:`core.silhouette_search.mask_grid` of every camera's :meth:`masks`."""
        from .silhouette_search import MaskGrid, mask_grid

        if self._grids is None:
            self._grids = [
                mask_grid(m) if m is not None else MaskGrid(np.zeros((0, 2)), np.zeros(0, bool), 2)
                for m in self.masks()
            ]
        return self._grids

    def part_counts(self, n_parts: int, min_views: int = 1) -> np.ndarray:
        """Pairs per body part at the last freeze, shape (P,); 0 for a part whose pairs
        come from fewer than ``min_views`` cameras with 10 or more pairs each."""
        if self.pairs is None or not len(self.pairs):
            return np.zeros(n_parts, int)
        counts = np.bincount(self.pairs.bone, minlength=n_parts)[:n_parts]
        if min_views > 1:
            C = len(self.cameras)
            per = np.bincount(self.pairs.bone * C + self.pairs.camera, minlength=n_parts * C)[
                : n_parts * C
            ].reshape(n_parts, C)
            counts = np.where((per >= 10).sum(axis=1) >= min_views, counts, 0)
        return counts

    def stats(
        self, skel: Skeleton, balls: Metaballs, theta: np.ndarray, root: np.ndarray, s: np.ndarray
    ) -> dict:
        """Re-pair at a (final) state: ``{"n": pairs, "rms_px": RMS of the pairs within
        3 knees, "inl": their share, "cost": Σ min(|r|, 3 knees)²}`` (pixels)."""
        self.freeze(skel, balls, theta, root, s)
        r = contour_block(skel, balls, theta, root, s, self.cameras, self.pairs, shape=False)[0]
        tau = 3.0 * self.cfg.huber_px
        inl = np.abs(r) <= tau
        return {
            "n": len(r),
            "inl": float(inl.mean()) if len(r) else 0.0,
            "rms_px": float(np.sqrt(np.mean(r[inl] ** 2))) if inl.any() else np.inf,
            "cost": float(np.sum(np.minimum(np.abs(r), tau) ** 2)),
        }

    def cameras_used(self, skel: Skeleton) -> dict:
        """``{part name: [camera names]}`` of the last freeze (empty before one)."""
        if self.selection is None:
            return {}
        use = self.selection.use
        return {
            skel.bone_names[p]: [self.cameras[c].name for c in np.flatnonzero(use[p])]
            for p in range(min(len(skel.bone_names), len(use)))
        }


# -- image contours of a scene ------------------------------------------------------------
@dataclass
class SceneContours:
    """Image occluding contours of a scene.

    Attributes
    ----------
    contours : list (F) of list (C) of list of Contour
    view_ok : (F, C) bool — the foreground of that view was plausible (covering between
        ``min_fg_frac`` and ``max_fg_frac`` of the image); contours of other views are empty
    camera_ok : (C,) bool — the camera's background model is usable (plausible
        foreground in at least half of the frames)
    messages : list of str
    """

    contours: list
    view_ok: np.ndarray
    camera_ok: np.ndarray
    messages: list


def contours_from_frames(
    frames: np.ndarray, cfg: ContourSettings | None = None
) -> tuple[list[list[Contour]], np.ndarray]:
    """Foreground contours of one camera's take (robust temporal median background).

    Parameters
    ----------
    frames : (N, H, W, 3) or (N, H, W) uint8

    Returns
    -------
    contours : list (N) of list of Contour (empty where the mask is implausible)
    ok : (N,) bool — plausible foreground (see :class:`SceneContours`)
    """
    from .background import fit_background

    cfg = cfg or ContourSettings()
    model = fit_background(frames, max_frames=cfg.background_frames)
    out, ok = [], np.zeros(len(frames), bool)
    for i, img in enumerate(frames):
        mask = model.foreground(img)
        frac = float(mask.mean())
        ok[i] = cfg.min_fg_frac <= frac <= cfg.max_fg_frac
        out.append(occluding_contours(mask, spacing=cfg.spacing_px) if ok[i] else [])
        ok[i] &= len(out[-1]) > 0
    return out, ok


def scene_contours(
    scene, cameras: list[Camera], n_frames: int, cfg: ContourSettings | None = None, progress=None
) -> SceneContours:
    """Image contours of the first ``n_frames`` frames of every camera of a scene
    (:func:`contours_from_frames` per camera, from the whole take's background)."""
    cfg = cfg or ContourSettings()
    C = len(scene.cameras)
    per_cam, oks, msgs = [], [], []
    for c, name in enumerate(scene.cameras):
        frames = np.array([scene.image(name, i, color=True) for i in range(scene.n_frames)])
        cons, ok = contours_from_frames(frames, cfg)
        per_cam.append(cons[:n_frames])
        oks.append(ok[:n_frames])
        if progress is not None:
            progress.update(c + 1, C, f"foreground contours: camera {name}")
    view_ok = np.stack(oks, axis=1) if oks else np.zeros((n_frames, 0), bool)
    camera_ok = view_ok.mean(axis=0) >= 0.5 if n_frames else np.zeros(C, bool)
    for c in np.flatnonzero(~camera_ok):
        msgs.append(
            f"camera {scene.cameras[c]}: no usable background/foreground "
            f"(plausible person mask in {int(view_ok[:, c].sum())} of {n_frames} "
            "frames): its contours are not used"
        )
        for f in range(n_frames):
            per_cam[c][f] = []
    view_ok &= camera_ok[None]
    contours = [[per_cam[c][f] for c in range(C)] for f in range(n_frames)]
    return SceneContours(contours, view_ok, camera_ok, msgs)


def contour_frames(
    cameras: list[Camera], contours: list[list[list[Contour]]], cfg: ContourSettings | None = None
) -> list[ContourFrame]:
    """One :class:`ContourFrame` per frame, sharing the cameras' cached rays."""
    rays = [camera_rays(c) for c in cameras]
    return [ContourFrame(cameras, fc, cfg, rays=rays) for fc in contours]
