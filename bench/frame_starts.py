"""Where each frame's fit lands from other starts, and whether its criteria could choose.

``python -m bench.frame_starts [SCENE] [--frames N] [--probe A-B] [--click-draw K]
[--setting NAME=VALUE ...]``

A frame's fit starts from the motion model's prediction.  This probe fits every frame
with points (after the shape frames) also from three other starts — the previous
frame's pose, the undamped extrapolation of the last two frames, and the truth's pose
solved onto the fitted skeleton (its metric joints, :func:`truth_pose`) — through the
same whole path (:meth:`core.fit_frame.FrameFitter.fit_frame`: the plain fit, the limb
search, the annealed retry, the silhouette retry).  Each start runs as a side branch on
a copy of the fitter's state; the sequence goes on from the prediction's fit, as the
default fit does.  Per frame and start it prints the fit's MPJPE against the truth, its
explain cost (m², the frame's criterion with points), the share of points it leaves
unexplained and the pixels where its body and the foreground disagree (the criterion of
frames fitted from contours alone), the two joints furthest off, and the truth's pose's
own disagreement.  If no start keeps a lost scene, or the criteria cannot tell the
truth's fit from the others, the starts are not the fix.  A frame fitted from contours
alone (the orthogonal rig) already tries the previous pose and the extrapolation
(``contour_starts``), so the probe adds only the truth's pose there.  ``--probe A-B``
limits the probe to those frames (the rest run as the default fit), ``--click-draw K``
moves the clicks as :mod:`bench.fit_spread`'s run K does.

A SCENE is a :data:`bench.fit.STUDIO_SCENES` name with its tracks under ``out/bench_fit``
(default ``dance_line3``, fitted on its first ``--frames`` frames, default 10).
"""

from __future__ import annotations

import argparse
import copy
from contextlib import contextmanager
from dataclasses import replace

import numpy as np

from bench.fit import ROOT
from bench.fit_spread import parse_settings, perturbed_clicks
from core import fit_frame as ff
from core.blas_threads import single_blas_thread
from core.evaluate import truth_joints
from core.fit_scene import run_scene
from core.fit_types import SequenceSettings
from core.landmarks import METRIC_JOINTS
from core.scene import load_scene
from core.skeleton import joint_jacobians, joint_positions


def truth_pose(skel, s, q, joints, iterations: int = 30) -> np.ndarray:
    """The pose (n + 3,) that puts the skeleton's metric joints at ``joints`` (M, 3),
    metres (Gauss–Newton from ``q``; twists the joints do not decide stay near ``q``)."""
    n = skel.n_dof
    idx = [skel.joint_index(j) for j in METRIC_JOINTS]
    th, rt = q[None, :n].copy(), q[None, n:].copy()
    for _ in range(iterations):
        x, jac, _ = joint_jacobians(skel, th, rt, s)
        a = np.concatenate([jac[0][idx].reshape(-1, n), np.tile(np.eye(3), (len(idx), 1))], 1)
        r = (x[0][idx] - joints).reshape(-1)
        step = -np.linalg.solve(a.T @ a + 1e-4 * np.eye(n + 3), a.T @ r)
        th[0] += step[:n]
        rt[0] += step[n:]
    return np.concatenate([th[0], rt[0]])


@contextmanager
def probed(truth_xyz, names, out, frames=None):
    """Patch :class:`core.fit_frame.FrameFitter` so that each frame (of ``frames``, a
    set, or all) is also fitted from the other starts: a frame with points from the
    previous pose, the extrapolation and the truth's pose, one from contours alone from
    the truth's pose (its fit already tries the other two); rows (frame, start, ok,
    per-joint errors (mm, :data:`METRIC_JOINTS`), cost, unexplained, pixels) go to
    ``out``."""
    fit_frame, record = ff.FrameFitter.fit_frame, ff.FrameFitter.record
    last = {}
    cols = [names.index(j) for j in METRIC_JOINTS]

    def mpjpe(fx, q, f):  # per metric joint, mm
        x = joint_positions(fx.skel, q[None, : fx.n], q[None, fx.n :], fx.s)[0]
        idx = [fx.skel.joint_index(j) for j in METRIC_JOINTS]
        return 1000 * np.linalg.norm(x[idx] - truth_xyz[f, cols], axis=1)

    def rec(fx, f, res, ok, why, stats):
        last["cost"] = np.nan if stats is None else stats["cost"]
        last["unex"] = np.nan if stats is None else stats["unexplained"]
        return record(fx, f, res, ok, why, stats)

    def pixels(fx, f, q):
        return fx.disagreement(f, q) if fx.cframe(f) is not None else np.nan

    def row(fx, f, name, ok, q):
        out.append((f, name, ok, mpjpe(fx, q, f), last["cost"], last["unex"], pixels(fx, f, q)))

    def probe(fx, f, q_pred, sig_pred, alternatives=(), **kw):
        starts = []
        if frames is not None and f not in frames:
            pass
        elif len(fx.frames[f].xyz) >= fx.cfg.min_points and len(alternatives):
            q_prev = alternatives[0]
            starts.append(("previous pose", q_prev))
            if f >= 2 and not fx.div[f - 2]:
                starts.append(
                    ("extrapolation", 2 * q_prev - np.r_[fx.theta[f - 2], fx.root[f - 2]])
                )
            q_true = truth_pose(fx.skel, fx.s, q_prev, truth_xyz[f, cols])
            starts.append(("truth's pose", q_true))
        elif f > 0 and not fx.div[f - 1]:
            # contours alone: the fit already starts from the previous pose and the
            # extrapolation too (``contour_starts``); the truth's pose is the one to add
            q_prev = np.r_[fx.theta[f - 1], fx.root[f - 1]]
            q_true = truth_pose(fx.skel, fx.s, q_prev, truth_xyz[f, cols])
            starts.append(("truth's pose", q_true))
        for name, q0 in starts:
            side = copy.copy(fx)
            for k, v in vars(fx).items():
                if isinstance(v, np.ndarray | list):
                    setattr(side, k, v.copy())
            ok, q = fit_frame(side, f, q0, sig_pred, alternatives, **kw)
            row(fx, f, name, ok, q)
        if starts:
            out.append((f, "truth's pose itself", True, mpjpe(fx, q_true, f), np.nan, np.nan,
                        pixels(fx, f, q_true)))  # fmt: skip
        ok, q = fit_frame(fx, f, q_pred, sig_pred, alternatives, **kw)
        row(fx, f, "prediction (kept)", ok, q)
        return ok, q

    ff.FrameFitter.fit_frame, ff.FrameFitter.record = probe, rec
    try:
        yield out
    finally:
        ff.FrameFitter.fit_frame, ff.FrameFitter.record = fit_frame, record


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", nargs="?", default="dance_line3")
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument(
        "--probe",
        default=None,
        metavar="A-B",
        help="probe only frames A to B (default every frame fitted)",
    )
    ap.add_argument(
        "--click-draw",
        type=int,
        default=0,
        help="the clicks moved by N(0, 0.5 px) with this seed, as bench.fit_spread's run",
    )
    ap.add_argument(
        "--setting",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a SequenceSettings field for the fit (JSON value), e.g. contour_unfold=false",
    )
    args = ap.parse_args(argv)
    settings = replace(SequenceSettings(), **parse_settings(args.setting, ap.error))
    frames = None
    if args.probe:
        try:
            a, b = (int(x) for x in args.probe.split("-"))
        except ValueError:
            ap.error(f"--probe: expected A-B, got {args.probe!r}")
        frames = set(range(a, b + 1))
    folder = ROOT / "out" / "bench_fit" / args.scene
    scene = load_scene(folder, check_images=False)
    if args.click_draw:
        clicks = perturbed_clicks(scene.clicks(), 0.5, args.click_draw)
        scene.clicks = lambda: clicks
    truth_xyz, names = truth_joints(scene.truth)
    rows = []
    with probed(truth_xyz, names, rows, frames), single_blas_thread():
        run_scene(
            scene,
            observations="tracks",
            model="complete",
            cues="both",
            tracks=folder / "tracks.npz",
            frames=args.frames,
            settings=settings,
        )
    draw = f"click draw {args.click_draw}" if args.click_draw else "exact clicks"
    print(f"{args.scene}: first {args.frames} frames, {draw}, cues both")
    print(f"{'frame':>5}  {'start':<22}{'accepted':>9}{'MPJPE mm':>10}{'cost m²':>11}"
          f"{'unexpl.':>9}{'pixels':>8}  worst joints, mm")  # fmt: skip
    last_f = None
    for f, name, ok, err, cost, unex, px in sorted(rows, key=lambda r: r[0]):
        lead = f"{f:>5}" if f != last_f else " " * 5
        last_f = f
        worst = ", ".join(f"{METRIC_JOINTS[j]} {err[j]:.0f}" for j in np.argsort(-err)[:2])
        print(f"{lead}  {name:<22}{'yes' if ok else 'no':>9}{err.mean():>10.1f} {cost:>10.4f}"
              f"{unex:>9.3f}{px:>8.0f}  {worst}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
