"""The body's shape fitted to the clicked frame's silhouettes.

A take whose clicked frame has too few 3-D points to shape the body (the orthogonal
rigs, bare skin) takes its metaball radii, and the centres of the parts
:class:`core.fit_contours.ContourSettings` frees, from that frame's occluding contours
(:func:`shape_from_silhouettes`, through :func:`core.contour_track.fit_shape_to_contours`),
each radius held about the template's by :func:`radius_sigma`.

Frames: world Z up, metres; cameras as in :mod:`core.camera` (pixels, OpenCV frame).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

#: σ of a metaball radius about the template's in the silhouette shape fit, metres
SHAPE_RADIUS_SIGMA_M = 0.02


def center_sigma(skel, balls, cfg) -> np.ndarray | None:
    """σ (M,) of each metaball centre in the silhouette shape fit (NaN: held), metres."""
    if cfg is None or cfg.shape_center_sigma_m is None:
        return None
    names = np.array(skel.bone_names)[balls.bone]
    free = np.isin(names, cfg.shape_center_parts) & ~np.isin(names, cfg.shape_held_parts)
    return np.where(free, cfg.shape_center_sigma_m, np.nan)


def radius_sigma(skel, balls, cfg) -> np.ndarray:
    """σ (M,) of each metaball's radii about the template's in the silhouette shape fit:
    ``cfg.shape_held_sigma_m`` for the parts whose template shape is kept, metres."""
    sigma = np.full(len(balls), SHAPE_RADIUS_SIGMA_M)
    if cfg is not None and cfg.shape_held_parts:
        held = np.isin(np.array(skel.bone_names)[balls.bone], cfg.shape_held_parts)
        sigma[held] = cfg.shape_held_sigma_m
    return sigma


def containment(cframe, cfg) -> dict:
    """The containment keywords of :func:`core.contour_shape.fit_shape_to_contours`."""
    if cfg is None or not cfg.shape_containment_px:
        return {}
    return {"fields": cframe.fields(), "sigma_contain_px": cfg.shape_containment_px}


def shape_from_silhouettes(init, cameras, cframe, msgs, cfg=None):
    """The initialisation with its metaball radii, the centres of
    ``cfg.shape_center_parts`` (:class:`core.fit_contours.ContourSettings`) and a refined
    pose fitted to the clicked frame's silhouettes
    (:func:`core.contour_track.fit_shape_to_contours`; the clicked pose held tightly)."""
    from .contour_track import ContourTrackSettings, fit_shape_to_contours

    tight = ContourTrackSettings(q_sigma_theta=0.01, q_sigma_root=0.002)
    balls, th, rt, rms = fit_shape_to_contours(
        init.skeleton,
        init.s,
        init.metaballs,
        init.theta,
        init.root_xyz,
        cameras,
        cframe.contours,
        tight,
        radius_prior_m=radius_sigma(init.skeleton, init.metaballs, cfg),
        rays=cframe.rays,
        center_prior_m=center_sigma(init.skeleton, init.metaballs, cfg),
        **containment(cframe, cfg),
    )
    if not np.isfinite(rms) or not (np.all(np.isfinite(th)) and np.all(np.isfinite(rt))):
        msgs.append(
            f"frame {init.frame}: too few silhouette contour pairs for the shape: "
            "the template shape is kept"
        )
        return init
    moved = np.linalg.norm(balls.center0 - init.metaballs.center0, axis=1) * 100
    shift = (
        f"; {int((moved > 0).sum())} metaball centres moved, {np.median(moved[moved > 0]):.1f}"
        f" cm median, {moved.max():.1f} cm at most"
        if moved.max() > 0
        else ""
    )
    held = cfg.shape_held_parts if cfg is not None else ()
    kept = f"; the template shape kept: {', '.join(held)}" if held else ""
    msgs.append(
        f"shape fitted to frame {init.frame}'s silhouettes (contour RMS {rms:.2f} px "
        f"before the last step{shift}{kept})"
    )
    return replace(init, metaballs=balls, theta=th, root_xyz=rt)
