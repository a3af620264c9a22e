"""The passes after a take's first sequence fit, and the take fitted a second time.

:func:`core.fit_scene.run_scene` prepares a take (observations, contour frames, the
click initialisation, the silhouette shape) and hands it here.  :func:`run_passes` runs
the sequence fit (:func:`core.fit.fit_sequence`) and the one pass after it that the
take asks for: the shape re-solved over several frames' silhouettes
(:func:`frames_shape_pass`), the motion tracked again with the first pass's whole-body
shape (:func:`second_pass`) or with its late shape (:func:`late_pass`).  Where the
silhouettes shaped the body and the texture flow follows it, :func:`refined_alternative`
fits the take again with LSM-refined flow corners and keeps the fit the foregrounds
explain better (:mod:`core.fit_choice`).

Frames: world Z up, metres; cameras as in :mod:`core.camera` (pixels, OpenCV frame).
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from .fit import fit_sequence
from .fit_silhouette_shape import radius_sigma
from .progress import prefixed


def run_passes(
    cframes,
    anchors,
    kw,
    timings,
    t_start,
    *,
    obs,
    init,
    settings,
    multi,
    silhouette_pass,
    contour_settings,
):
    """The sequence fit and the pass after it that :func:`core.fit_scene.run_scene` chose: the shape
    over several frames, the second pass with the written shape, or the late shape."""
    res = fit_sequence(
        obs, init, settings, contours=cframes, defer_shape=multi or not silhouette_pass, **kw
    )
    if multi and (~res.state.quality.diverged).sum() > 1:
        return frames_shape_pass(
            obs, init, settings, res, cframes, anchors, kw, timings, t_start, contour_settings
        )
    if silhouette_pass and res.shape is not None and res.shape.frame_ok.any():
        return second_pass(
            obs,
            init,
            settings,
            res,
            cframes,
            anchors,
            kw,
            timings,
            time.perf_counter() - t_start,
        )
    if res.late_shape is not None:
        return late_pass(obs, init, settings, res, cframes, anchors, kw, timings, t_start)
    return res


def choose_refined(settings, flow) -> bool:
    """Whether a fit with the sequence settings ``settings`` and the flow settings
    ``flow`` is made again with refined corners (a take the silhouettes shaped)."""
    return bool(settings.flow_choice and not flow.refine_lsm)


def refined_alternative(first, scene, cameras, cframes, cfg, kw, timings, passes, progress):
    """The take fitted again with LSM-refined flow corners; the fit whose body the
    foregrounds explain better is returned (:func:`core.fit_choice.choose`), with a
    message giving both totals."""
    from .fit_choice import choose

    t0 = time.perf_counter()
    anchors = flow_anchors(scene, cameras, replace(cfg, refine_lsm=True), cframes)
    kw = {**kw, "flow": anchors, "progress": prefixed(progress, "refined corners: ")}
    alt_timings: dict = {}
    second = run_passes(fresh(cframes, None), anchors, kw, alt_timings, t0, **passes)
    best, totals = choose([first.state, second.state], cameras, cframes)
    timings["refined_alternative"] = time.perf_counter() - t0
    kept = ("Lucas–Kanade's corners", "LSM-refined corners")[best]
    note = (
        "texture flow: the take fitted with Lucas–Kanade's corners and with LSM-refined "
        f"ones, their bodies disagreeing with the foregrounds at {totals[0]:,.0f} / "
        f"{totals[1]:,.0f} pixels over the take: the fit with {kept} kept"
    )
    res = (first, second)[best]
    return replace(res, messages=res.messages + [note])


def second_pass(obs, init, settings, first, cframes, anchors, kw, timings, seconds):
    """The motion fitted again, tracked with the whole-body shape of the ``first`` pass.

    A take shaped from one frame's silhouettes tracks a shape that only that posture
    showed; the first pass's written shape follows the silhouettes (and any points) of
    frames spread over the take.  The second pass keeps it (``shape = "template"``:
    nothing to re-solve without points), on fresh contour frames and flow anchors; the
    result carries the first pass's shape record.
    """
    timings["first_pass"] = seconds
    res = fit_sequence(
        obs,
        replace(init, metaballs=first.state.metaballs),
        replace(settings, shape="template", late_shape_points=None),
        contours=fresh(cframes, anchors),
        **kw,
    )
    note = (
        "second pass: the motion tracked with the first pass's whole-body shape "
        f"({int(first.state.quality.diverged.sum())} -> "
        f"{int(res.state.quality.diverged.sum())} diverged frames)"
    )
    shape_msgs = [m for m in first.messages if m.startswith("whole-body shape")]
    return replace(res, shape=first.shape, messages=shape_msgs + [note] + res.messages)


def frames_shape_pass(obs, init, settings, first, cframes, anchors, kw, timings, t_start, cfg):
    """The motion fitted again with the radii of several of the ``first`` pass's frames.

    The clicked frame's silhouettes shaped the body
    (:func:`core.fit_silhouette_shape.shape_from_silhouettes`); the radii are re-solved
    over ``cfg.shape_fit_frames`` fitted frames, evenly spaced among those not diverged
    (:func:`core.contour_shape_frames.fit_shape_to_frames`), then the take is fitted
    again from the clicks with that shape.  The whole-body shape written to the state
    starts from the clicked frame's (``shape_start``).
    """
    from .contour_shape_frames import fit_shape_to_frames
    from .contour_track import ContourTrackSettings

    timings["first_pass"] = time.perf_counter() - t_start
    st = first.state
    ok = np.flatnonzero(~st.quality.diverged)
    pick = np.unique(ok[np.round(np.linspace(0, len(ok) - 1, cfg.shape_fit_frames)).astype(int)])
    sigma = np.repeat(radius_sigma(init.skeleton, init.metaballs, cfg)[:, None], 3, axis=1)
    if cfg.shape_frames_along_sigma_m is not None:
        sigma[:, 2] = cfg.shape_frames_along_sigma_m
    balls, _, _, rms = fit_shape_to_frames(
        init.skeleton,
        init.s,
        init.metaballs,
        st.theta[pick],
        st.root_xyz[pick],
        kw["cameras"],
        [cframes[f].contours for f in pick],
        ContourTrackSettings(),
        radius_prior_m=sigma,
        pose_sigma_rad=cfg.shape_frames_pose_sigma_rad,
        root_sigma_m=cfg.shape_frames_root_sigma_m,
        rays=cframes[pick[0]].rays,
    )
    if not np.isfinite(rms):
        note = "shape over several frames: too few contour pairs, the clicked frame's kept"
        return replace(first, messages=first.messages + [note])
    moved = np.abs(balls.radii - init.metaballs.radii) * 1000
    most, axis = np.unravel_index(np.argmax(moved), moved.shape)
    note = (
        f"shape re-solved over frames {pick.tolist()}'s silhouettes (contour RMS "
        f"{rms:.2f} px before the last step; radii moved {np.median(moved):.0f} mm median, "
        f"{moved.max():.0f} mm at most, {init.skeleton.bone_names[init.metaballs.bone[most]]}"
        f"'s {'xyz'[axis]}): the motion fitted again with it"
    )
    kw = {**kw, "progress": prefixed(kw.get("progress"), "second pass (shape over frames): ")}
    res = fit_sequence(
        obs,
        replace(init, metaballs=balls),
        settings,
        contours=fresh(cframes, anchors),
        defer_shape=True,
        shape_start=init.metaballs,
        **kw,
    )
    return replace(res, messages=[note] + res.messages)


def views_spread_deg(cameras, point) -> float:
    """The largest angle between two cameras' lines of sight to ``point`` (3,), degrees."""
    d = np.array([np.asarray(point, float) - cam.center for cam in cameras])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return float(np.degrees(np.arccos(np.clip((d @ d.T).min(), -1.0, 1.0))))


def fresh(cframes, anchors):
    """Contour frames without a fit's cached state, and the flow's anchors cleared."""
    from .fit_contours import ContourFrame

    if anchors is not None:
        anchors.clear()
    if cframes is None:
        return None
    return [
        None if cf is None else ContourFrame(cf.cameras, cf.contours, cf.cfg, rays=cf.rays)
        for cf in cframes
    ]


def late_pass(obs, init, settings, first, cframes, anchors, kw, timings, t_start):
    """The motion fitted again, tracked with the ``first`` pass's late shape
    (:mod:`core.fit_late_shape`: the parts the shape frames hardly saw, shaped from the
    fitted take)."""
    timings["first_pass"] = time.perf_counter() - t_start
    late = first.late_shape
    kw = {**kw, "progress": prefixed(kw.get("progress"), "second pass (late shape): ")}
    res = fit_sequence(obs, init, settings, contours=fresh(cframes, anchors), shape0=late, **kw)
    return replace(res, messages=[late.message()] + res.messages)


def flow_anchors(scene, cameras, flow, cframes):
    """The :class:`core.fit_flow.FlowAnchors` of a scene: its grey images, read on demand
    and kept for the last few frames only (the flow reads two neighbouring frames)."""
    from .fit_flow import FlowAnchors, FlowSettings

    cache: dict = {}

    def image(c, f):
        if (c, f) not in cache:
            if len(cache) >= 4 * len(cameras):
                del cache[next(iter(cache))]  # the oldest read
            cache[c, f] = scene.image(c, f)
        return cache[c, f]

    cfg = flow if isinstance(flow, FlowSettings) else FlowSettings()
    rays = None if not cframes else cframes[0].rays
    return FlowAnchors(cameras, image, cfg, rays=rays)
