"""Surface and tracking on the default sample scene, against the true mesh.

``python -m bench.tracking [--scene sample_scenes/walk_line3] [--frames N] [--gap N]``

Prints: surface points at frame 0 from 5 clicked seeds and their distance to the true
mesh, then without depth outliers (``--surface-depth-dev``, the points that are
tracked); the survival of the frame-0 points: strictly (measured in every frame) and
bridged (the same trajectory measured at the first and the last frame, with every
run of unmeasured frames at most ``--gap`` frames long and bridged by a flagged
position, :func:`through_with_gaps`); the ceilings set by visibility (frame-0 points
that the true mesh shows to two or more cameras in every frame, :func:`truth_views`;
and with runs of fewer than two views of at most ``--gap`` frames) with the survival
among those points; the live count; which step of the tracker first lost each lost
frame-0 point, for all of them and for those visible in every frame
(:func:`loss_breakdown`, :mod:`core.track_diagnose`), with the cameras the occlusion
test skipped although the truth sees them, the true error of the points the depth
test dropped, and how many survivors the trajectory filters would hit; tracked
positions against the same material point carried by the true mesh (barycentric
coordinates on the nearest triangle of the mesh at the trajectory's first frame),
over all, measured and bridged point-frames separately; the filters on 5 % injected
false trajectories; speed in frames/s (wall and CPU, with the load average) with the
point count; the temporal success rate with the 3-D Kalman (EKF) prediction against
the 2-D linear prediction at the same small search box (``--compare-frames`` frames,
no regeneration; the first step, where neither predictor has a velocity yet, uses the
wide 29 px box for both).
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

from bench.meshtruth import nearest_on_mesh
from core.scene import load_scene
from core.surface import measure_surface, seeds_from_clicks, subset
from core.track_diagnose import tally
from core.track_smooth import depth_outliers
from core.tracking import filter_trajectories, track


def material_truth(xyz, start, vertices, faces):
    """True positions (F, P, 3) of the material points under each trajectory's start."""
    F, P = vertices.shape[0], len(start)
    out = np.full((F, P, 3), np.nan)
    for s in np.unique(start):  # loop over start frames, not points
        idx = np.flatnonzero(start == s)
        p0 = xyz[s, idx]
        ok = np.all(np.isfinite(p0), axis=1)
        idx, p0 = idx[ok], p0[ok]
        _, face, bary = nearest_on_mesh(p0, vertices[s], faces)
        out[:, idx] = np.einsum("pk,fpkd->fpd", bary, vertices[:, faces[face]])
    return out


def tracked_point_errors(tracks: dict, vertices, faces, gross_m: float = 0.05) -> dict:
    """How far a tracker's output lies from the truth's material points.

    Parameters
    ----------
    tracks : a ``tracks.npz`` as a dict: ``xyz`` (F, P, 3) metres (NaN where not
        measured), ``start`` (P,) the trajectories' first frames, optional
        ``measured`` (F, P) bool and ``removed`` (P,) bool (the filters' verdict)
    vertices : (F, V, 3) the true mesh per frame, metres; faces : (T, 3)
    gross_m : an error beyond this counts as gross (a point on another part)

    Returns
    -------
    dict with ``n`` (point-frames compared: measured, not removed), ``median_mm``,
    ``p95_mm``, ``gross_pct`` (share beyond ``gross_m``, %), ``worst_frame`` (of the
    highest mean error) and that mean, ``worst_frame_mean_mm``
    """
    xyz = np.asarray(tracks["xyz"], float)
    F, P = xyz.shape[:2]
    use = np.all(np.isfinite(xyz), axis=-1)
    if "measured" in tracks:
        use &= np.asarray(tracks["measured"], bool)
    if "removed" in tracks:
        use &= ~np.asarray(tracks["removed"], bool)[None]
    if not use.any():
        return {"n": 0}
    start = np.asarray(tracks["start"], int)
    err = np.linalg.norm(xyz - material_truth(xyz, start, vertices, faces), axis=-1)
    use &= np.isfinite(err)
    e = err[use] * 1000.0
    mean = [err[f, use[f]].mean() * 1000.0 if use[f].any() else 0.0 for f in range(F)]
    worst = int(np.argmax(mean))
    return {
        "n": int(use.sum()),
        "median_mm": float(np.median(e)),
        "p95_mm": float(np.percentile(e, 95)),
        "gross_pct": float(100.0 * np.mean(e > gross_m * 1000.0)),
        "worst_frame": worst,
        "worst_frame_mean_mm": float(mean[worst]),
    }


def truth_views(cameras, vertices, faces, xyz, start, tol_m=0.01, min_cos=0.2, per_face=6, seed=0):
    """Cameras that truly see each tracked material point: (F, P, C) bool.

    The material point under each trajectory's start (as :func:`material_truth`) is
    visible in a camera when it faces it (cosine between its triangle's normal and the
    direction to the camera above ``min_cos``: grazing views are not matchable) and
    lies within ``tol_m`` of a z-buffer of the true mesh splatted into that camera
    (every vertex and ``per_face`` random points per triangle, nearest per pixel).
    """
    F, P = vertices.shape[0], len(start)
    face, bary = np.full(P, -1), np.zeros((P, 3))
    for s in np.unique(start):
        idx = np.flatnonzero(start == s)
        ok = np.all(np.isfinite(xyz[s, idx]), axis=1)
        _, face[idx[ok]], bary[idx[ok]] = nearest_on_mesh(xyz[s, idx[ok]], vertices[s], faces)
    w = np.random.default_rng(seed).dirichlet(np.ones(3), size=(len(faces), per_face))
    have = np.flatnonzero(face >= 0)
    seen = np.zeros((F, P, len(cameras)), bool)
    for f in range(F):
        pts = np.vstack(
            [vertices[f], np.einsum("tkj,tjd->tkd", w, vertices[f][faces]).reshape(-1, 3)]
        )
        tri = vertices[f][faces[face[have]]]
        p = np.einsum("pk,pkd->pd", bary[have], tri)
        nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        for j, cam in enumerate(cameras):
            wd, ht = cam.size
            z = np.full(ht * wd, np.inf)
            uv = np.rint(cam.project(pts)).astype(int)
            ins = (uv[:, 0] >= 0) & (uv[:, 0] < wd) & (uv[:, 1] >= 0) & (uv[:, 1] < ht)
            np.minimum.at(
                z, uv[ins, 1] * wd + uv[ins, 0], np.linalg.norm(pts[ins] - cam.center, axis=1)
            )
            q = np.rint(cam.project(p)).astype(int)
            inq = (q[:, 0] >= 0) & (q[:, 0] < wd) & (q[:, 1] >= 0) & (q[:, 1] < ht)
            v = cam.center - p
            d = np.linalg.norm(v, axis=1)
            cosang = np.einsum("pd,pd->p", nrm, v) / d
            zq = np.where(
                inq, z[np.clip(q[:, 1], 0, ht - 1) * wd + np.clip(q[:, 0], 0, wd - 1)], -np.inf
            )
            seen[f, have, j] = inq & (d <= zq + tol_m) & (cosang > min_cos)
    return seen


def through_with_gaps(measured, alive, max_gap):
    """Points kept to the last frame with short flagged gaps: (P,) bool.

    ``measured`` and ``alive`` (F, P) bool: a point counts when it is measured in the
    first and the last frame, has a (measured or bridged) position in every frame, and
    no run of unmeasured frames is longer than ``max_gap``.
    """
    run = np.zeros(measured.shape[1], int)
    longest = np.zeros(measured.shape[1], int)
    for m in measured:  # loop over frames, points batched
        run = np.where(m, 0, run + 1)
        longest = np.maximum(longest, run)
    return measured[0] & measured[-1] & alive.all(axis=0) & (longest <= max_gap)


def loss_breakdown(log, m0, stay_vis, views):
    """Print which tracker step first lost each frame-0 point (``log[i]["reason"]``).

    ``m0`` (F, P0) measured; ``stay_vis`` (P0,) seen by two or more cameras in every
    frame per the truth; ``views`` (F, P0, C) truth visibility per camera.
    """
    F, p0 = m0.shape
    lost = ~m0.all(axis=0)
    first = np.argmax(~m0, axis=0)  # first unmeasured frame
    code = np.full(p0, -1, np.int8)
    occ_wrong = np.zeros(p0, bool)
    for f in range(1, F):
        k = np.flatnonzero(lost & (first == f))
        if len(k) == 0 or "reason" not in log[f - 1]:
            continue
        code[k] = log[f - 1]["reason"][k]
        occ = log[f - 1]["occ"][k]
        occ_wrong[k] = np.any(occ & views[f, k], axis=1)
    print(
        f"why frame-0 points were lost (the step that first lost each; frames "
        f"{int(first[lost].min()) if lost.any() else '-'}-"
        f"{int(first[lost].max()) if lost.any() else '-'}):"
    )
    for name, sel in (
        ("all lost", lost),
        ("lost, seen by >= 2 cameras in every frame", lost & stay_vis),
    ):
        t = tally(code[sel])
        other = int(sel.sum()) - sum(t.values())
        items = ", ".join(f"{k} {v}" for k, v in t.items() if v) + (
            f", (unrecorded) {other}" if other else ""
        )
        print(f"  {name} ({int(sel.sum())}): {items}")
    sel = lost & stay_vis
    if sel.any():
        print(
            f"  of those always-visible lost points, {int((occ_wrong & sel).sum())} had a "
            f"camera skipped by the occlusion test that the truth sees at that frame; "
            f"frames where they were first lost: "
            f"{np.bincount(first[sel], minlength=F).tolist()}"
        )


def inject(xyz, frac, rng):
    """Append false trajectories (jumps, drifts, stuck points) copied from good ones."""
    F, P, _ = xyz.shape
    k = max(1, int(round(frac * P)))
    src = rng.choice(P, k, replace=False)
    fake = xyz[:, src].copy()
    for j in range(k):
        k0 = rng.integers(2, F - 2)
        kind = j % 3
        if kind == 0:
            fake[k0:, j] += rng.choice([-1, 1], 3) * rng.uniform(0.02, 0.05)
        elif kind == 1:
            fake[:, j] += np.cumsum(rng.normal(0, 0.01, (F, 3)), axis=0)
        else:
            fake[k0:, j] = fake[k0, j]
    return np.concatenate([xyz, fake], axis=1), P


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="sample_scenes/walk_line3")
    ap.add_argument("--frames", type=int, default=None)
    ap.add_argument("--compare-frames", type=int, default=12)
    ap.add_argument("--compare-radius", type=int, default=3)
    ap.add_argument(
        "--predict",
        choices=("ekf", "linear"),
        default="ekf",
        help="prediction of the main tracking run",
    )
    ap.add_argument(
        "--no-anchor",
        action="store_true",
        help="no re-anchoring on key templates (frame-to-frame matching only)",
    )
    ap.add_argument(
        "--max-dormant",
        type=int,
        default=None,
        help="frames a lost point stays dormant for re-acquisition "
        "(default: core.tracking.track's)",
    )
    ap.add_argument(
        "--track-kw",
        default="{}",
        help="more keyword arguments of core.tracking.track as JSON, e.g. '{\"agree_px\": 0.3}'",
    )
    ap.add_argument(
        "--surface-depth-dev",
        type=float,
        default=0.01,
        help="drop frame-0 points farther than this in depth from their "
        "neighbours' median before tracking, metres (0: keep all)",
    )
    ap.add_argument(
        "--gap",
        type=int,
        default=5,
        help="longest flagged gap of the bridged survival figure, frames",
    )
    ap.add_argument(
        "--steps", action="store_true", help="print the tracker's counts of every frame step"
    )
    ap.add_argument(
        "--no-compare", action="store_true", help="skip the EKF-vs-linear prediction comparison"
    )
    args = ap.parse_args(argv)
    sc = load_scene(args.scene)
    cams = sc.calibration()
    V, faces = sc.truth["vertices"].astype(float), sc.truth["faces"]
    nf = sc.n_frames if args.frames is None else min(args.frames, sc.n_frames)
    seeds = seeds_from_clicks(sc.clicks(), sc.cameras, 5)
    t0 = time.perf_counter()
    surf = measure_surface([sc.image(c, 0) for c in sc.cameras], cams, seeds)
    ts = time.perf_counter() - t0
    d, _, _ = nearest_on_mesh(surf.xyz, V[0], faces)
    print(
        f"surface frame 0: {len(surf)} points from {len(seeds)} seeds in {ts:.1f} s; "
        f"distance to true mesh median {1000 * np.median(d):.2f} mm, "
        f"95% {1000 * np.percentile(d, 95):.2f} mm"
    )
    if args.surface_depth_dev > 0:
        out = depth_outliers(
            surf.xyz, np.mean([c.center for c in cams], axis=0), args.surface_depth_dev
        )
        surf, d = subset(surf, ~out), d[~out]
        print(
            f"  without depth outliers (> {1000 * args.surface_depth_dev:.0f} mm from the "
            f"median of 8 neighbours; the points tracked): {len(surf)} points, median "
            f"{1000 * np.median(d):.2f} mm, 95% {1000 * np.percentile(d, 95):.2f} mm"
        )

    def frames(i):
        return [sc.image(c, i) for c in sc.cameras]

    t1, c1 = time.perf_counter(), time.process_time()
    kw = {"anchor": not args.no_anchor, **json.loads(args.track_kw)}
    if args.max_dormant is not None:
        kw["max_dormant"] = args.max_dormant
    log: list = []
    tr = track(frames, cams, surf, nf, sc.fps, predict=args.predict, log=log, **kw)
    dt, dc = time.perf_counter() - t1, time.process_time() - c1
    alive = tr.alive
    p0 = len(surf)
    m0 = tr.measured[:, :p0]
    strict = m0.all(axis=0)
    bridged = through_with_gaps(tr.measured[:, :p0], alive[:, :p0], args.gap)
    views = truth_views(cams, V[:nf], faces, tr.xyz, tr.start)[:, :p0]
    vis2 = views.sum(axis=2) >= 2
    stay_vis = vis2.all(axis=0)
    print(f"tracking {nf} frames ({args.predict} prediction, {kw}), {p0} frame-0 points:")
    print(f"  strict, measured in every frame: {100 * strict.mean():.1f} %")
    print(
        f"  bridged, identity kept to the last frame (measured there) with flagged gaps "
        f"of <= {args.gap} frames: {100 * bridged.mean():.1f} %"
    )
    print(
        f"  truth visibility (true mesh z-buffer, facing cos > 0.2): seen by >= 2 cameras "
        f"in every frame {100 * stay_vis.mean():.1f} % (the ceiling of the strict figure); "
        f"among these, strict {100 * strict[stay_vis].mean():.1f} %, bridged "
        f"{100 * bridged[stay_vis].mean():.1f} %"
    )
    ceil_b = through_with_gaps(vis2, np.ones_like(vis2), args.gap)
    print(
        f"  truth: seen by >= 2 cameras in the first and last frame with runs of fewer "
        f"than 2 views of <= {args.gap} frames {100 * ceil_b.mean():.1f} % (the ceiling of "
        f"the bridged figure); among these, bridged {100 * bridged[ceil_b].mean():.1f} %"
    )
    print(
        "  the same truth ceiling for other longest gaps: "
        + ", ".join(
            f"{g} frames {100 * through_with_gaps(vis2, np.ones_like(vis2), g).mean():.1f} %"
            for g in (0, 2, 5, 10, 20, nf)
        )
    )
    miss = ceil_b & ~bridged
    first = np.argmax(~m0, axis=0)
    again = (m0 & (np.arange(nf)[:, None] >= first[None])).any(axis=0) & miss
    print(
        f"  of the {int(miss.sum())} points under the bridged ceiling not bridged: "
        f"{int((miss & ~again).sum())} never measured again after their first loss, "
        f"{int((again & ~m0[-1]).sum())} measured again but not at the last frame, "
        f"{int((again & m0[-1]).sum())} measured again with a longer gap"
    )
    print(
        f"  live at last frame {int(alive[-1].sum())} = "
        f"{100 * alive[-1].sum() / alive[0].sum():.1f} % of the first ({int(alive[0].sum())})"
    )
    back = alive[:, :p0].all(axis=0) & ~strict
    print(
        f"re-acquisition: {sum(s.get('reacquired_dormant', 0) for s in log)} re-acquisitions "
        f"of dormant points in all; {int(back.sum())} frame-0 points have a position in "
        f"every frame only with bridged frames ({int((alive[:, :p0] & ~m0).sum())} bridged "
        f"point-frames); re-anchored temporal matches {sum(s.get('anchored', 0) for s in log)} "
        f"of {sum(s.get('temporal_ok', 0) for s in log)}"
    )
    print(
        f"speed: {(nf - 1) / dt:.3f} frames/s wall, {(nf - 1) / dc:.3f} frames per CPU "
        f"second, with {int(alive.sum(axis=1).mean())} points per frame on average (load "
        f"average {os.getloadavg()[0]:.1f})"
    )
    loss_breakdown(log, m0, stay_vis, views)
    if args.steps:
        keys = (
            "live_before",
            "measured",
            "coasting",
            "coast_predicted",
            "dormant",
            "reacquired_dormant",
            "regenerated",
            "jump_seeded",
            "depth_outliers",
            "depth_retried",
        )
        for i, st in enumerate(log):
            print(
                f"  step {i}->{i + 1}: "
                + ", ".join(f"{k} {st[k]}" for k in keys if k in st)
                + (f"; re-acquisition {st['reacquire_stats']}" if st.get("reacquire_stats") else "")
            )
    P = tr.xyz.shape[1]
    rej = [
        np.pad(
            s_["depth_rejected"],
            ((0, P - len(s_["depth_rejected"])), (0, 0)),
            constant_values=np.nan,
        )
        for s_ in log
        if "depth_rejected" in s_
    ]
    if len(rej) == nf - 1:
        rej = np.concatenate([np.full((1, P, 3), np.nan), np.stack(rej)])
        tru = material_truth(np.where(np.isfinite(rej), rej, tr.xyz), tr.start, V[:nf], faces)
        e = np.linalg.norm(rej - tru, axis=2)
        e = e[np.isfinite(e)]
        if e.size:
            print(
                f"  points dropped by the depth test: {e.size} point-frames, their error "
                f"median {1000 * np.median(e):.2f} mm, 95% {1000 * np.percentile(e, 95):.2f} "
                f"mm, {100 * np.mean(e < 0.005):.0f} % within 5 mm"
            )
    flt = filter_trajectories(tr.xyz[:, :p0], sc.fps)
    hit = flt.removed | flt.truncated
    print(
        f"  trajectory filters (not applied to the survival figures): they would hit "
        f"{int((hit & strict).sum())} of the {int(strict.sum())} strict survivors, "
        f"{int((hit & bridged & ~strict).sum())} of the {int((bridged & ~strict).sum())} "
        f"bridged-only ones"
    )
    truth = material_truth(tr.xyz, tr.start, V[:nf], faces)
    err = np.linalg.norm(tr.xyz - truth, axis=2)
    for name, sel in (
        ("all tracked", np.isfinite(err)),
        ("measured only", tr.measured),
        ("bridged only", np.isfinite(err) & ~tr.measured),
    ):
        e = err[sel]
        if e.size == 0:
            continue
        print(
            f"tracked 3-D vs material truth, {name}: median {1000 * np.median(e):.2f} mm, "
            f"95% {1000 * np.percentile(e, 95):.2f} mm over {e.size} point-frames"
        )
    ncmp = min(args.compare_frames, nf)
    for pred in () if args.no_compare else ("ekf", "linear"):
        log: list = []
        # the first step has no velocity for either predictor: both get the wide box
        # there, then the same small fixed box; counted from frame 2 on
        tc = track(
            frames,
            cams,
            surf,
            ncmp,
            sc.fps,
            predict=pred,
            adaptive=False,
            ncc_radius=args.compare_radius,
            first_radius=14,
            regen_every=0,
            log=log,
            **kw,
        )
        seen = sum(s.get("seen", 0) for s in log[2:])
        ok = sum(s.get("temporal_ok", 0) for s in log[2:])
        print(
            f"prediction {pred:6s} at a fixed {2 * args.compare_radius + 1} px box, "
            f"{ncmp} frames: temporal matches ok {100 * ok / max(seen, 1):.1f} % "
            f"(frames 2-{ncmp - 1}), frame-0 points measured in every frame "
            f"{100 * tc.measured[:, :p0].all(axis=0).mean():.1f} %"
        )
    rng = np.random.default_rng(0)
    full = alive.all(axis=0)
    xyz_all, n_good = inject(tr.xyz[:, full], 0.05, rng)
    res = filter_trajectories(xyz_all, sc.fps)
    hit = res.removed | res.truncated
    print(
        f"filters with {xyz_all.shape[1] - n_good} injected false trajectories: "
        f"{100 * hit[n_good:].mean():.1f} % of false removed/truncated, "
        f"{100 * hit[:n_good].mean():.1f} % of good ones hit"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
