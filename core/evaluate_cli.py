"""``python -m core evaluate SCENE FIT [--json] [--plot PNG]``: score a fit against truth.

Prints a readable table; ``--json`` adds one JSON object as the last line of stdout
(keys: ``mpjpe_mm``, ``max_joint_error_pct_height``, ``segment_orientation_rmse_deg``,
``segment_direction_rmse_deg``, ``frames``, ``diverged_frames``, ``per_joint_mm``, ...);
``--plot`` writes PNG error curves.  Metric definitions: :mod:`core.evaluate`.
"""

from __future__ import annotations

import argparse
import json
import math


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", help="scene folder with truth.npz")
    parser.add_argument("fit", help="fitted-state file (fit.json)")
    parser.add_argument(
        "--json", action="store_true", help="print the metrics as one JSON object on the last line"
    )
    parser.add_argument("--plot", metavar="PNG", help="write per-frame error curves here")


def _fmt(v: float, digits: int = 3) -> str:
    return "n/a" if not math.isfinite(v) else f"{v:.{digits}f}"


def format_table(ev) -> str:
    """The human-readable report of an :class:`core.evaluate.Evaluation`."""
    lines = [
        f"frames {ev.frames}  (diverged {ev.diverged_frames}, left out of the statistics)",
        f"MPJPE                        {_fmt(ev.mpjpe_mm)} mm",
        f"max joint error              {_fmt(ev.max_joint_error_pct_height, 4)} % of height "
        f"({ev.height_m:.3f} m); frames within 1 %: {100 * ev.frames_within_1pct:.1f} %",
        f"segment orientation RMSE     {_fmt(ev.segment_orientation_rmse_deg)} deg "
        "(upper/lower arms and legs)",
        f"segment direction RMSE       {_fmt(ev.segment_direction_rmse_deg)} deg "
        "(their long axes alone, without the twist)",
        f"metaball surface             {_fmt(ev.surface_mm, 1)} mm from the true mesh "
        "(mean, by area)",
        f"acceleration error           {_fmt(ev.accel_error_mm, 2)} mm/frame² "
        "(jitter against the truth's motion)",
        "",
        f"{'joint':<14}{'mean mm':>10}",
    ]
    lines += [f"{j:<14}{_fmt(v):>10}" for j, v in ev.per_joint_mm.items()]
    lines += ["", f"{'segment':<14}{'RMSE deg':>10}{'max deg':>10}{'axis deg':>10}"]
    lines += [
        f"{s:<14}{_fmt(ev.per_segment_rmse_deg[s]):>10}{_fmt(ev.per_segment_max_deg[s]):>10}"
        f"{_fmt(ev.per_segment_direction_rmse_deg.get(s, math.nan)):>10}"
        for s in ev.per_segment_rmse_deg
    ]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from .evaluate import evaluate_state, plot
    from .scene import load_scene
    from .state import read_state

    scene = load_scene(args.scene, check_images=False)
    truth_path = scene.root / "truth.npz"
    state = read_state(args.fit)
    ev = evaluate_state(state, scene.truth, truth_path, args.fit)
    print(format_table(ev))
    if args.plot:
        path = plot(ev, args.plot, fps=scene.fps, title=f"{scene.name}: {args.fit}")
        print(f"wrote {path}")
    if args.json:
        print(json.dumps(_finite(ev.to_json())))
    return 0


def _finite(obj):
    """JSON-safe copy: non-finite floats become null."""
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj
