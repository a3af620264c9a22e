"""The late shape: parts the shape frames hardly saw, shaped from the fitted take.

The per-part shape solve of :func:`core.fit.fit_sequence` runs on the shape frames next
to the clicked one, and the shape is fixed afterwards.  A part those frames showed with
few points keeps the template's radii there.  make demo's walk shows its left hand to
two cameras only from frame 3 on (0 points on the hand bone in the two shape frames,
330–380 over every 5th frame of the take, over four click draws) and the lower back
hardly (0–10 points there, 106–256 over the take).
Once the hand's points arrive (frame 6) they sit on a forearm and hand thinner than the
template's, and the fit bends the elbow to put them on the template's surface: the left
wrist goes 13 → 33 mm off at frame 6 and stays 20–27 mm off.

:func:`late_shape` re-solves the per-part shape (:func:`core.fitting.fit`,
``solve="shape"``, the fitted poses held) over every ``step``-th fitted frame of the
take and keeps the new radii and centres only for the bones that had fewer than
``missed_points`` points in the shape frames and at least ``min_points`` over the
take.  The other bones keep the shape frames' shape: re-solving every bone moved the
well-shaped legs (make demo's walk, run 0: knees 3.5 → 12 mm, MPJPE 12.9 → 14.9 mm).
:func:`core.fit_scene.run_scene` then fits the motion a second time, starting from that
shape (``SequenceSettings.late_shape_points``; the second pass solves the shape frames
again from it, anchored to it).

Measured (``bench.fit_spread SCENE --runs 4``, docs/design.md "The late shape"): make
demo's walk 12.9 / 16.1 / 12.7 / 15.1 → 11.1 / 13.5 / 12.4 / 12.2 mm (median 14.0 →
12.3), mostly in the arm no camera sees and the head; the second pass alone (no bone
re-shaped) 10.6 / 15.1 / 13.7 / 13.5.  jumps_line3 has no such bone and is fitted once,
the same to the last digit; the orthogonal rig's takes have no points and are not
touched.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .fit_types import frame_observations
from .fitting import FitSettings, fit


@dataclass
class LateShape:
    """The per-part shape the second pass tracks with.

    Attributes
    ----------
    radii : (M, 3) metaball semi-axes, metres
    centers : (M, 3) metaball centres in their bones' frames, metres before scaling
    bones : tuple of str — the bones whose metaballs were re-shaped
    frames : (K,) int — the fitted frames the shape was solved over
    shape_points, take_points : (B,) int — points per bone in the shape frames and
        in ``frames``, at the fitted poses
    """

    radii: np.ndarray
    centers: np.ndarray
    bones: tuple
    frames: np.ndarray
    shape_points: np.ndarray
    take_points: np.ndarray

    def message(self) -> str:
        """One line for the fit's messages."""
        return (
            f"late shape: {', '.join(self.bones)} re-shaped over frames "
            f"{', '.join(map(str, self.frames))} (too few points in the shape frames); "
            "the motion fitted again with it"
        )


def shape_settings(cfg) -> FitSettings:
    """The per-part shape solve's :class:`core.fitting.FitSettings` from the sequence
    settings ``cfg`` (:class:`core.fit_types.SequenceSettings`)."""
    return FitSettings(
        **{
            **cfg.fit.__dict__,
            "max_nfev": cfg.max_nfev_shape,
            "fit_scales": cfg.shape_scales,
            "free_centers": cfg.shape_centers,
            "sigma_radius": cfg.shape_sigma_radius,
            "sigma_center": cfg.shape_sigma_center,
        }
    )


def late_shape(
    fx,
    shape_frames,
    template,
    step: int = 5,
    min_points: int = 100,
    missed_points: int = 30,
    max_unexplained: float = 0.1,
):
    """The late shape of a fitted take, or None when no bone qualifies.

    Parameters
    ----------
    fx : :class:`core.fit_frame.FrameFitter` after the motion (its poses ``theta``,
        ``root``, flags ``div``, counts ``n_pts`` and current shape)
    shape_frames : the frames the shape was solved over
    template : :class:`core.metaballs.Metaballs` — the bounds of the radii and centres
        (:func:`core.fitting.fit` ``shape_ref``)
    step : every step-th fitted frame with points joins the solve
    min_points : a bone is re-shaped when the solve's frames give it at least this
        many points ...
    missed_points : ... and the shape frames gave it fewer than this
    max_unexplained : a take whose fit leaves more than this share of the points
        unexplained in its median fitted frame (``fx.unexpl``) is not re-shaped: its
        poses may be wrong (dance_line3, lost at its first kick: 0.19; make demo's
        walk 0.066)

    Returns
    -------
    LateShape or None
    """
    cfg = fx.cfg
    nb = len(fx.skel.bone_names)
    fitted = [f for f in range(fx.nf) if not fx.div[f] and fx.n_pts[f] >= cfg.min_points]
    share = fx.unexpl[fitted]
    share = share[np.isfinite(share)]
    if not fitted or (len(share) and np.median(share) > max_unexplained):
        return None
    use = fitted[::step]
    shape_pts = np.zeros(nb, int)
    for g in shape_frames:
        if not fx.div[g]:
            part = fx.stored_labels(g)
            shape_pts += np.bincount(part[part >= 0], minlength=nb)
    take_pts = np.zeros(nb, int)
    obs, keep = [], []
    for g in use:
        part = fx.stored_labels(g)
        if (part >= 0).sum() >= cfg.min_points:
            take_pts += np.bincount(part[part >= 0], minlength=nb)
            obs.append(frame_observations(fx.frames[g], part, None, cfg.sigma_pred, fx.n))
            keep.append(g)
    grow = (shape_pts < missed_points) & (take_pts >= min_points)
    if not grow.any() or not obs:
        return None
    rs = fit(
        fx.skel,
        fx.balls,
        obs,
        fx.theta[keep],
        fx.root[keep],
        fx.s,
        fx.radii,
        solve="shape",
        settings=shape_settings(cfg),
        shape_ref=template,
    )
    moved = grow[fx.balls.bone]
    radii = np.where(moved[:, None], rs[0].radii, fx.radii)
    centers = np.where(moved[:, None], rs[0].centers, fx.balls.center0)
    bones = tuple(fx.skel.bone_names[b] for b in np.flatnonzero(grow))
    return LateShape(radii, centers, bones, np.array(keep), shape_pts, take_pts)
