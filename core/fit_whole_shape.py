"""The whole-body shape of a sequence fit's shape frames (``SequenceSettings.shape = "fit"``).

:func:`whole_body_shape` runs :func:`core.shape_fit.fit_shape` on the points of the
shape frames that :func:`core.fit.fit_sequence` fitted, their poses held, and reports it
as a :class:`core.fit_types.ShapeRecord`.  Lengths in metres, angles in radians.
"""

from __future__ import annotations

import time

import numpy as np

from .fit_types import FramePoints, ShapeRecord
from .metaballs import Metaballs
from .shape_fit import ShapeSettings, fit_shape
from .skeleton import Skeleton


def has_outline(cframe) -> bool:
    """Whether a frame's :class:`core.fit_contours.ContourFrame` (or None) holds any
    image contour."""
    return cframe is not None and any(len(c) for c in cframe.contours)


def written_shape(
    skel: Skeleton,
    start: Metaballs,
    s: np.ndarray,
    theta: np.ndarray,
    root: np.ndarray,
    frames: list[FramePoints],
    contours: list | None,
    fitted: np.ndarray,
    n_points: np.ndarray,
    unobserved: np.ndarray,
    f0: int,
    cfg,
    cameras: list | None,
    msgs: list,
    progress=None,
):
    """The whole-body shape written to the state after the motion (``SequenceSettings``
    ``shape = "fit"``, ``shape_fit_track = False``).

    At the fitted poses ``theta`` (F, n) / ``root`` (F, 3) of the ``fitted`` (F,) bool
    frames with enough points (``n_points`` (F,) ≥ ``cfg.min_points``) or with
    silhouettes in ``contours`` (list (F) of :class:`core.fit_contours.ContourFrame` or
    None): with silhouettes, ``cfg.shape_fit_silhouette_frames`` of them spread over the
    take and fitted to points and silhouettes — the silhouettes of the parts those
    frames measured (``unobserved`` (F, n) bool), and of the parts whose contours the
    pose fit skips (the head: held to the trunk, not guessed); else the
    ``cfg.shape_fit_frames`` nearest the clicked frame ``f0``, to points alone.

    Returns
    -------
    (Metaballs or None, :class:`ShapeRecord` or None) — None when no frame qualifies
    (a message says so).
    """
    nf = len(frames)
    outline = np.array([has_outline(None if contours is None else contours[f]) for f in range(nf)])
    good = np.flatnonzero(fitted & ((n_points >= cfg.min_points) | outline))
    use = shape_fit_frames(
        good, f0, cfg.shape_fit_frames, cfg.shape_fit_silhouette_frames if outline.any() else 0
    )
    if not len(use):
        msgs.append(
            "whole-body shape fit: no fitted frame with points or silhouettes, the "
            "shape tracked with is kept"
        )
        return None, None
    skip = next((contours[f].cfg.skip_parts for f in use if outline[f]), ())
    balls, _, rec = whole_body_shape(
        skel,
        start,
        s,
        theta,
        root,
        frames,
        use.tolist(),
        cameras,
        cfg.shape_fit,
        msgs,
        progress,
        contours=contours if outline.any() else None,
        parts=measured_parts(skel, unobserved, always=skip),
    )
    return balls, rec


def measured_parts(skel: Skeleton, unobserved: np.ndarray, always: tuple = ()) -> np.ndarray:
    """(F, B) bool: the body parts each frame placed by measurement.

    A part is placed by inference when any of its own angles or of its ancestors' is
    ``unobserved`` ((F, n) bool, :func:`core.fit_bridge.unobserved`: the angle and all
    its descendants held for want of observations): held, mirrored or bridged, its pose
    is a guess.  (A pelvis whose own outline is hidden by the thighs but whose children
    are seen is placed by them: observed.)  The bones named in ``always`` count as
    measured in every frame.
    """
    chain = np.asarray(unobserved, bool) @ skel.ancestors().T  # (F, n): any on the chain
    dof_bone = skel.dof_bones()
    out = np.ones((chain.shape[0], len(skel.bone_names)), bool)
    for b in range(len(skel.bone_names)):
        on = dof_bone == b
        if on.any() and skel.bone_names[b] not in always:
            out[:, b] = ~chain[:, on].any(axis=1)
    return out


def shape_fit_frames(good: np.ndarray, f0: int, near: int, spread: int) -> np.ndarray:
    """Frames (sorted) for the whole-body shape fit after the motion.

    ``spread`` > 0 (silhouettes available): that many of the ``good`` frames, evenly
    spread over them (the limbs turned different ways constrain the shape from more
    sides); else the ``near`` good frames nearest the clicked frame ``f0``.
    """
    good = np.asarray(good, int)
    if not len(good):
        return good
    if spread > 0:
        k = min(int(spread), len(good))
        return np.unique(good[np.linspace(0, len(good) - 1, k).round().astype(int)])
    return np.sort(good[np.argsort(np.abs(good - f0), kind="stable")][:near])


def whole_body_shape(
    skel: Skeleton,
    template: Metaballs,
    s: np.ndarray,
    theta: np.ndarray,
    root: np.ndarray,
    frames: list[FramePoints],
    use: list[int],
    cameras: list | None,
    settings: ShapeSettings | None,
    msgs: list,
    progress=None,
    contours: list | None = None,
    parts: np.ndarray | None = None,
) -> tuple[Metaballs, np.ndarray, ShapeRecord]:
    """The whole-body shape of ``frames[use]`` at their held poses.

    Runs :func:`core.shape_fit.fit_shape` from the ``template`` metaballs (its prior)
    with the bone scales ``s`` (G,), the poses ``theta[use]`` (K, n) radians and
    ``root[use]`` (K, 3) metres, every point's σ the larger of its own and the shape
    fit's ``sigma_point`` (metres).  ``contours`` (list (F) of
    :class:`core.fit_contours.ContourFrame` or None, optional): the shape also follows
    those frames' silhouettes, and a frame needs no points; ``parts`` ((F, B) bool,
    optional, :func:`measured_parts`) limits those to the parts each frame measured.
    Appends its message to ``msgs``; with no usable frame the template is kept.
    ``progress`` (a :class:`core.progress.Progress`, optional) is updated every round of
    the shape fit, and cancels it.

    Returns
    -------
    (metaballs, radii (M, 3) metres, :class:`ShapeRecord`)
    """
    sc = settings or ShapeSettings()
    t0 = time.perf_counter()
    use = np.asarray(use, int)
    if not len(use):
        msgs.append("whole-body shape fit: no fitted shape frame, the template is kept")
        rec = ShapeRecord(use, np.zeros(0, bool), np.zeros(0), False, "no fitted shape frame", 0.0)
        return template.copy(), template.radii.copy(), rec
    cf = (
        None
        if contours is None
        else [contours[f] if has_outline(contours[f]) else None for f in use]
    )
    if cf is not None and not any(c is not None for c in cf):
        cf = None
    if cf is not None and cameras is None:  # the silhouettes' own cameras
        cameras = next(c.cameras for c in cf if c is not None)
    sf = fit_shape(
        skel,
        template,
        s,
        theta[use],
        root[use],
        [frames[f].xyz for f in use],
        cameras,
        sigma=[np.maximum(frames[f].sigma, sc.sigma_point) for f in use],
        settings=sc,
        progress=None
        if progress is None
        else (lambda k, n: progress.update(k, n, "whole-body shape")),
        contours=None if cf is None else [None if c is None else c.contours for c in cf],
        rays=None if cf is None else next(c.rays for c in cf if c is not None),
        parts=None if parts is None else [parts[f] for f in use],
    )
    rec = ShapeRecord(
        use,
        sf.frame_ok.copy(),
        sf.rms_m.copy(),
        bool(sf.converged),
        sf.message,
        time.perf_counter() - t0,
    )
    rms = sf.rms_m[sf.frame_ok & np.isfinite(sf.rms_m)]
    sil = sf.silhouette_rms_px[np.isfinite(sf.silhouette_rms_px)]
    stats = ([f"surface RMS {1e3 * np.mean(rms):.2f} mm"] if len(rms) else []) + (
        [f"silhouette RMS {np.mean(sil):.2f} px"] if len(sil) else []
    )
    msgs.append(
        f"whole-body shape fit of frames {use.tolist()}: {sf.message}"
        + (f" ({', '.join(stats)})" if stats else "")
    )
    if not sf.frame_ok.any():
        return template.copy(), template.radii.copy(), rec
    out = sf.metaballs
    if cf is not None:  # the outline was fitted as rendered: render it so everywhere
        out.visible_scale = blend_scale(skel, out, s, theta[use], root[use])
    return out, out.radii.copy(), rec


def blend_scale(
    skel: Skeleton, balls: Metaballs, s: np.ndarray, theta: np.ndarray, root: np.ndarray
) -> np.ndarray:
    """``visible_scale`` (M, 3) whose ellipsoids follow the blended surface.

    The median over the poses ``theta`` (K, n) / ``root`` (K, 3) of
    :func:`core.metaball_surface.render_radii` over the radii: the contours, the camera
    selection and the segmentation then render the surface the silhouettes shaped (a
    metaball's share of the blend changes a little with the pose as its neighbours
    come closer or part).
    """
    from .metaball_surface import render_radii
    from .skeleton import forward

    vis = [
        render_radii(skel, forward(skel, th[None], rt[None], s), balls, s)
        for th, rt in zip(np.atleast_2d(theta), np.atleast_2d(root), strict=True)
    ]
    return np.median(np.stack(vis), axis=0) / balls.radii
