"""How far one fit's figures move when its input moves a little.

``python -m bench.fit_spread [SCENE] [--runs N] [--click-noise PX] [--cues C] [--jobs J]
[--flow-sigma PX] [--flow NAME=VALUE ...] [--setting NAME=VALUE ...] [--shape NAME=VALUE ...]
[--contour NAME=VALUE ...] [--states DIR] [--visibility]``

The sequence fit makes discrete choices — which camera a part uses, whether a limb
search's move is kept, which corners the texture flow lifts — so on a scene where a limb
is hardly observed a change far below what any figure could resolve can send that limb
down another path.  One run's MPJPE is then one draw, and a setting that looks better
by a millimetre in one run may be noise.  This benchmark fits the same tracks ``N``
times: run 0 with the scene's clicks as they are, runs 1…N−1 with every click moved by
Gaussian noise of ``--click-noise`` pixels (seeded by the run number; 0.5 px is well
under what a person clicking reaches).  It prints each run's MPJPE, diverged frames,
limb-segment RMSE, share of frames within 1 % of the height and the written metaball
surface's mean distance to the true mesh, then the median and range over the runs,
overall and per joint.  ``--flow-sigma`` sets the texture flow's
a-priori σ (:class:`core.fit_flow.FlowSettings` ``sigma_px``), so that two settings can
be compared by their medians rather than by one run each; ``--flow`` sets any field of
:class:`core.fit_flow.FlowSettings` (VALUE in JSON: ``reference=false``),
``--setting`` one of :class:`core.fit_types.SequenceSettings` (``shape_scales=true``)
and ``--shape`` one of the whole-body shape fit's :class:`core.shape_fit.ShapeSettings`
(``sigma_one_sided=0.0005``), ``--contour`` one of the contour observations'
:class:`core.fit_contours.ContourSettings` (``shape_held_parts='["head"]'``).
``--states DIR`` writes each run's fitted state as
``DIR/runK.json``, for ``core evaluate`` or ``bench.visibility``; ``--visibility`` adds
each run's visibility index against the true mesh (:func:`bench.visibility.compare`,
outer surface, every 5th frame: the #7 figure).

``--drag JOINT,...`` does, before each fit, what a user dragging those joints' empties
in a side view of Blender's viewport does at best (:func:`dragged_clicks`): each joint's
clicked point moves along its forward intersection's least-certain axis (the cameras'
depth on ``line3``) to the point of that line nearest the truth; run with and without
it on the same runs to see what correcting a click's depth is worth.

A SCENE is a scene folder or a :data:`bench.fit.STUDIO_SCENES` name (rendered and
cached under ``out/bench_fit`` on first use; default: the default sample scene).  The
fits run in-process (:func:`core.fit_scene.run_scene` with ``observations="tracks"``
and the complete model, as ``core fit --observations tracks`` does), ``--jobs`` at a
time (default 2), each on one BLAS thread; the tracks are the scene's own
``tracks.npz`` (the default scene: :func:`bench.fit.default_tracks`), tracked first
when missing.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from core.landmarks import OPTIONAL_CLICK_JOINTS

ROOT = Path(__file__).resolve().parents[1]


def perturbed_clicks(clicks: dict, noise_px: float, seed: int) -> dict:
    """A copy of ``Scene.clicks()`` with every (u, v) moved by N(0, noise_px²) per axis;
    ``seed`` 0 or ``noise_px`` 0 returns the clicks unchanged."""
    if seed == 0 or noise_px <= 0:
        return clicks
    rng = np.random.default_rng(seed)
    # the optional joints (toes) are drawn last, so that clicking them leaves the moves
    # of the others as they were: runs with and without them are paired
    order = sorted(clicks["joints"], key=lambda j: (j in OPTIONAL_CLICK_JOINTS, j))
    joints = {
        j: {
            c: np.asarray(uv, float) + rng.normal(0.0, noise_px, 2)
            for c, uv in sorted(clicks["joints"][j].items())
        }
        for j in order
    }
    return {**clicks, "joints": joints}


def dragged_clicks(clicks: dict, cams, truth: dict, joints) -> dict:
    """``clicks`` with each of ``joints`` re-clicked at the point of its intersection's
    long axis (the largest-variance direction of ``ClickPoints.cov``) nearest the
    truth's joint at the clicked frame — a depth corrected by hand, the rest kept."""
    from core.evaluate import truth_joints
    from core.fit_init import clicks_at, triangulate_clicks

    cp = triangulate_clicks(clicks, cams)
    txyz, names = truth_joints(truth)
    moved = {}
    for j in joints:
        k = cp.names.index(j)
        axis = np.linalg.eigh(cp.cov[k])[1][:, 2]
        t = txyz[clicks["frame"], names.index(j)]
        moved[j] = cp.xyz[k] + axis * (axis @ (t - cp.xyz[k]))
    return clicks_at(clicks, cams, moved)


def fit_once(
    scene_dir: str,
    tracks: str,
    cues: str,
    noise_px: float,
    seed: int,
    flow_sigma_px: float | None = None,
    settings: dict | None = None,
    drag: tuple = (),
    flow: dict | None = None,
    shape: dict | None = None,
    states: str | None = None,
    visibility: bool = False,
    contour: dict | None = None,
) -> dict:
    """One in-process fit of the scene's tracks with perturbed clicks; its figures.
    ``flow_sigma_px``: the texture flow's σ (None: ``FlowSettings``' default);
    ``settings``: :class:`SequenceSettings` fields (None: its defaults); ``flow``:
    :class:`core.fit_flow.FlowSettings` fields (None: its defaults); ``shape``:
    :class:`core.shape_fit.ShapeSettings` fields of the written shape (None: its
    defaults); ``states``: a folder to write the fitted state to (``run{seed}.json``);
    ``visibility``: also the mean |ΔVI| against the true mesh (NaN when not asked);
    ``contour``: :class:`core.fit_contours.ContourSettings` fields (None: its defaults)."""
    from core.blas_threads import single_blas_thread
    from core.evaluate import evaluate_state
    from core.fit_contours import ContourSettings
    from core.fit_flow import FlowSettings
    from core.fit_scene import run_scene
    from core.fit_types import SequenceSettings
    from core.scene import load_scene
    from core.shape_fit import ShapeSettings
    from core.state import write_state

    scene = load_scene(Path(scene_dir), check_images=False)
    clicks = perturbed_clicks(scene.clicks(), noise_px, seed)
    if drag:
        clicks = dragged_clicks(clicks, scene.calibration(), scene.truth, drag)
    scene.clicks = lambda: clicks  # the fit's initialisation reads them from here
    flow = dict(flow or {})
    if flow_sigma_px is not None:
        flow["sigma_px"] = flow_sigma_px
    flow = FlowSettings(**flow) if flow else "auto"
    settings = dict(settings or {})
    if shape:
        settings["shape_fit"] = ShapeSettings(**shape)
    t0 = time.perf_counter()
    with single_blas_thread():
        res = run_scene(
            scene,
            observations="tracks",
            model="complete",
            cues=cues,
            tracks=tracks,
            flow=flow,
            settings=SequenceSettings(**settings) if settings else None,
            contour_settings=ContourSettings(**contour) if contour else None,
        )
    wall = time.perf_counter() - t0
    for m in getattr(res, "messages", []):  # how the silhouettes shaped the body, and
        if m.startswith(("shape ", "texture flow: ")):  # which flow's fit was kept
            print(f"run {seed}: {m}", flush=True)
    ev = evaluate_state(res.state, scene.truth)
    vi = np.nan
    if visibility:
        from bench.visibility import compare

        frames = range(0, scene.n_frames, 5)
        vi = compare(res.state, scene.truth, scene.calibration(), frames, outer_only=True)
        vi = vi["mean_abs_diff"]
    if states is not None:
        Path(states).mkdir(parents=True, exist_ok=True)
        write_state(Path(states) / f"run{seed}.json", res.state)
    return {
        "seed": seed,
        "mpjpe_mm": ev.mpjpe_mm,
        "diverged": ev.diverged_frames,
        "segments_deg": ev.segment_orientation_rmse_deg,
        "segment_axes_deg": ev.segment_direction_rmse_deg,
        "within_1pct": ev.frames_within_1pct,
        "per_joint_mm": ev.per_joint_mm,
        "per_segment_deg": ev.per_segment_rmse_deg,
        "accel_mm": ev.accel_error_mm,
        "surface_mm": ev.surface_mm,
        "visibility": vi,
        "wall_s": wall,
    }


def parse_settings(items: list[str], error, kind=None, flag: str = "--setting") -> dict:
    """``["name=json", ...]`` -> ``{name: value}`` of the fields of the dataclass
    ``kind`` (default :class:`core.fit_types.SequenceSettings`; scalar values, or a list
    of them for a tuple field); ``error(message)`` on a malformed item, an unknown field
    or an object value.  ``flag`` names the option in the messages."""
    from dataclasses import fields

    from core.fit_types import SequenceSettings

    kind = SequenceSettings if kind is None else kind
    known = {f.name: f for f in fields(kind)}
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or name not in known:
            error(f"{flag} {item!r}: expected NAME=VALUE with NAME a {kind.__name__} field")
        try:
            out[name] = json.loads(value)
        except json.JSONDecodeError:
            error(f'{flag} {item!r}: VALUE is not JSON (true, 0.5, "fit")')
        v = out.get(name)
        listed = isinstance(v, list) and "tuple" in str(known[name].type)
        if isinstance(v, dict) or (isinstance(v, list) and not listed):
            error(f"{flag} {item!r}: only a number, true/false, null or a string")
        if listed:
            out[name] = tuple(v)
    return out


def scene_tracks(scene: Path) -> Path:
    """The tracks a ``core fit --observations tracks`` of ``scene`` would use, tracked
    first (``python -m core track``) when missing."""
    from bench.fit import _is_default, default_tracks

    if _is_default(scene):
        return default_tracks()
    path = scene / "tracks.npz"
    if not path.is_file():
        print(f"tracking {scene.name} first (python -m core track; minutes) …", flush=True)
        subprocess.run(
            [sys.executable, "-m", "core", "track", str(scene), "-o", str(path)],
            check=True,
            cwd=ROOT,
        )
    return path


def summary(rows: list[dict]) -> dict:
    """Median, min and max over the runs of MPJPE and of every joint's error."""
    m = np.array([r["mpjpe_mm"] for r in rows])
    acc = np.array([r["accel_mm"] for r in rows])
    joints = list(rows[0]["per_joint_mm"])
    pj = np.array([[r["per_joint_mm"][j] for j in joints] for r in rows])
    return {
        "mpjpe_median_mm": float(np.median(m)),
        "mpjpe_min_mm": float(m.min()),
        "mpjpe_max_mm": float(m.max()),
        "accel_median_mm": float(np.median(acc)),
        "surface_median_mm": float(np.median([r.get("surface_mm", np.nan) for r in rows])),
        "visibility_median": float(np.median([r.get("visibility", np.nan) for r in rows])),
        "per_joint": {
            j: (float(np.median(pj[:, k])), float(pj[:, k].min()), float(pj[:, k].max()))
            for k, j in enumerate(joints)
        },
    }


def main(argv: list[str] | None = None) -> int:
    from bench.fit import DEFAULT, RENDERS, STUDIO_SCENES, _resolve

    ap = argparse.ArgumentParser(
        prog="python -m bench.fit_spread", description=__doc__.splitlines()[0]
    )
    ap.add_argument(
        "scene",
        nargs="?",
        default=str(DEFAULT),
        help="scene folder or studio scene name (default: the sample scene)",
    )
    ap.add_argument("--runs", type=int, default=5, help="fits, the first unperturbed")
    ap.add_argument("--first", type=int, default=0, help="the first run's number (its seed)")
    ap.add_argument("--click-noise", type=float, default=0.5, help="pixels, per axis")
    ap.add_argument("--cues", default="both", choices=("texture", "contours", "both"))
    ap.add_argument("--jobs", type=int, default=2, help="fits at a time")
    ap.add_argument(
        "--flow-sigma",
        type=float,
        default=None,
        help="the texture flow's a-priori σ, pixels (default: FlowSettings')",
    )
    ap.add_argument(
        "--setting",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a SequenceSettings field, VALUE in JSON (repeatable)",
    )
    ap.add_argument(
        "--flow",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a FlowSettings field, VALUE in JSON (repeatable): reference=false",
    )
    ap.add_argument(
        "--shape",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a ShapeSettings field of the written shape, VALUE in JSON (repeatable)",
    )
    ap.add_argument(
        "--contour",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a ContourSettings field, VALUE in JSON (repeatable)",
    )
    ap.add_argument(
        "--states", type=Path, default=None, help="write each run's state as DIR/runK.json"
    )
    ap.add_argument(
        "--visibility",
        action="store_true",
        help="also each run's visibility index against the true mesh (~15 s a run)",
    )
    ap.add_argument(
        "--drag",
        default="",
        metavar="JOINT,...",
        help="move these joints' clicks along their depth onto the truth first",
    )
    ap.add_argument(
        "--tracks",
        type=Path,
        default=None,
        help="fit these tracks (a `core track` .npz) instead of the scene's own",
    )
    ap.add_argument("--json", type=Path, default=None, help="write the figures here")
    args = ap.parse_args(argv)
    drag = tuple(j for j in args.drag.split(",") if j)
    if args.runs < 1 or args.jobs < 1:
        ap.error("--runs and --jobs must be at least 1")
    if (args.flow_sigma is not None or args.flow) and args.cues != "both":
        ap.error("--flow-sigma and --flow need --cues both (the flow runs only with both cues)")

    from core.fit_contours import ContourSettings
    from core.fit_flow import FlowSettings
    from core.shape_fit import ShapeSettings

    settings = parse_settings(args.setting, ap.error)
    flow = parse_settings(args.flow, ap.error, FlowSettings, "--flow")
    shape = parse_settings(args.shape, ap.error, ShapeSettings, "--shape")
    contour = parse_settings(args.contour, ap.error, ContourSettings, "--contour")
    scene, _ = _resolve(args.scene, RENDERS)
    if not scene.is_dir():
        ap.error(
            f"{args.scene}: no such scene folder, nor a studio scene ({', '.join(STUDIO_SCENES)})"
        )
    if args.tracks is not None and not args.tracks.is_file():
        ap.error(f"--tracks {args.tracks}: no such file")
    try:
        tracks = scene_tracks(scene) if args.tracks is None else args.tracks
    except subprocess.CalledProcessError:
        ap.error(f"{scene}: tracking failed (python -m core track printed why, above)")
    print(
        f"{scene.name}: {args.runs} fits (runs {args.first}–{args.first + args.runs - 1}) "
        f"of {tracks}, cues {args.cues}, clicks moved by "
        f"N(0, {args.click_noise} px) in runs 1..{args.first + args.runs - 1}"
        + ("" if args.flow_sigma is None else f", flow σ {args.flow_sigma} px")
        + "".join(f", {k} = {v!r}" for k, v in settings.items())
        + "".join(f", flow {k} = {v!r}" for k, v in flow.items())
        + "".join(f", shape {k} = {v!r}" for k, v in shape.items())
        + "".join(f", contour {k} = {v!r}" for k, v in contour.items())
        + (f", dragged in depth onto the truth: {', '.join(drag)}" if drag else ""),
        flush=True,
    )
    print(
        f"{'run':>3}  {'MPJPE mm':>8}  {'diverged':>8}  {'segments °':>10}  {'axes °':>6}  "
        f"{'≤1 % height':>11}  {'accel mm/f²':>11}  {'surface mm':>10}  {'VI':>6}  {'s':>5}",
        flush=True,
    )
    rows = []
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        futs = [
            pool.submit(
                fit_once,
                str(scene),
                str(tracks),
                args.cues,
                args.click_noise,
                k,
                args.flow_sigma,
                settings,
                drag,
                flow,
                shape,
                None if args.states is None else str(args.states),
                args.visibility,
                contour,
            )
            for k in range(args.first, args.first + args.runs)
        ]
        for fut in futs:
            r = fut.result()
            rows.append(r)
            print(
                f"{r['seed']:>3}  {r['mpjpe_mm']:8.1f}  {r['diverged']:8d}  "
                f"{r['segments_deg']:10.1f}  {r['segment_axes_deg']:6.1f}  "
                f"{100 * r['within_1pct']:10.0f}%  "
                f"{r['accel_mm']:11.2f}  {r['surface_mm']:10.2f}  {r['visibility']:6.3f}  "
                f"{r['wall_s']:5.0f}",
                flush=True,
            )
    s = summary(rows)
    print(
        f"MPJPE median {s['mpjpe_median_mm']:.1f} mm, range {s['mpjpe_min_mm']:.1f}–"
        f"{s['mpjpe_max_mm']:.1f} mm over {len(rows)} runs; acceleration error median "
        f"{s['accel_median_mm']:.2f} mm/frame²; metaball surface median "
        f"{s['surface_median_mm']:.2f} mm"
        + ("" if not args.visibility else f"; visibility index median {s['visibility_median']:.3f}")
    )
    print(
        "per joint, median (min–max) mm: "
        + ", ".join(f"{j} {a:.0f} ({b:.0f}–{c:.0f})" for j, (a, b, c) in s["per_joint"].items())
    )
    if args.json:
        args.json.write_text(json.dumps({"scene": scene.name, "runs": rows, **s}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
