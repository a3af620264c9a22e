"""The ``somacap`` command line inside Blender (``blender -c somacap …``).

::

    blender -c somacap fit SCENE --out take.blend [--target character.blend] [--fit fit.json]
                              [--cues texture|contours|both] [--feet-from-points] [--smooth]
                              [--prediction-start-only] [--one-pass] [--one-flow]
    blender -c somacap retarget fit.json --target character.blend --out take.blend
    blender -c somacap batch TAKES_DIR --out OUT_DIR [--target character.blend] [--cues …]
                              [--feet-from-points] [--smooth] [--prediction-start-only]
                              [--one-pass] [--one-flow]

The same commands run with the ``bpy`` module of the project's environment through the
launcher: ``python -m addon.launch fit SCENE --out take.blend`` (from the repository root).

``fit`` builds a new file with the scene's cameras (footage as background), the body
(armature, metaballs, action named after the take) and, with ``--target``, the motion
retargeted onto the character.  It uses ``--fit FILE``, else ``SCENE/fit.json``, else
runs core's fitter.  ``--cues`` chooses the fit's observations (texture: tracked
surface points, the default; contours: silhouettes, for bare skin; both: the most
accurate, about 2.7x the CPU time) and always fits anew: ``SCENE/fit.json`` is then
not used (nor overwritten); it cannot be combined with ``--fit``.
``--feet-from-points`` turns each foot about its shin at the clicked frame to the
heading of the surface points under it (core's ``SequenceSettings(foot_heading=True)``,
``core fit --feet-from-points``; off by default, and without effect with contours
alone) and fits anew like ``--cues`` (nor can it be combined with ``--fit``).
``--smooth`` smooths the fitted motion over the take — each joint's path by a Kalman
smoother whose smoothness that path's likelihood chooses, then the angles solved to it
(core's
``SequenceSettings(smooth_motion=True)``, ``core fit --smooth``; less jitter on walks
and jumps, off by default as a sudden kick of one limb gets spread over its
neighbouring frames) and fits anew in the same way; with ``--feet-from-points`` the
fit has both.
``--prediction-start-only`` fits a frame without texture points (contours alone) from
the prediction only, not also from the previous frame's pose and its extrapolation
(core's ``SequenceSettings(contour_starts=False)``, ``core fit
--prediction-start-only``; about half the fit time on a rig without points, but a fast
limb may be lost, e.g. on the orthogonal rig) and fits anew in the same way.
``--one-pass`` fits the motion once (core's ``SequenceSettings(late_shape_points=
None)``, ``core fit --one-pass``): by default the bones the first frames hardly saw
are shaped over the fitted take and the motion is fitted a second time from that
shape (:mod:`core.fit_late_shape`; about 2x the fit time where a bone qualifies); it
too fits anew.
``--one-flow`` fits a take that the silhouettes shape (no texture points at the clicked
frame, e.g. the orthogonal rig) and that follows the texture flow once, with
Lucas–Kanade's flow corners (core's ``SequenceSettings(flow_choice=False)``, ``core fit
--one-flow``): by default such a take is fitted a second time with LSM-refined flow
corners and the fit the foregrounds explain better is kept (:mod:`core.fit_choice`;
about twice the fit time there); it too fits anew.
``retarget`` builds the same file from a fitted state, without cameras.
``batch`` converts every take of a folder (scene folders and ``*.json`` states) into
``OUT_DIR/<take>.blend``, continues past a failing take, prints the failures and exits
with status 1 when any take failed; ``--cues``, ``--feet-from-points``, ``--smooth``,
``--prediction-start-only``, ``--one-pass`` and ``--one-flow`` refit every scene folder (``.json``
states are used as they are).  Bad input: one line ``somacap: error: …``, status 2.
"""

from __future__ import annotations

import argparse
import sys
import traceback
from pathlib import Path

from . import _core


def _cue_help() -> dict:
    from .pipeline import FIT_CUES

    return FIT_CUES


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="somacap", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True)
    f = sub.add_parser("fit", help="fit a scene folder and write a .blend")
    f.add_argument("scene", type=Path)
    f.add_argument("--out", type=Path, required=True)
    f.add_argument(
        "--target",
        type=Path,
        help="character .blend to retarget onto, or 'rigify' for a Rigify human "
        "rig generated from Blender's meta-rig",
    )
    f.add_argument("--fit", type=Path, help="use this fitted state instead of fitting")
    f.add_argument("--take", help="take / action name (default: the scene folder name)")
    r = sub.add_parser("retarget", help="build a fitted state and retarget it")
    r.add_argument("state", type=Path)
    r.add_argument("--target", type=Path, required=True)
    r.add_argument("--out", type=Path, required=True)
    r.add_argument("--take", help="take / action name (default: the file's stem)")
    b = sub.add_parser("batch", help="convert a folder of takes")
    b.add_argument("takes", type=Path)
    b.add_argument("--out", type=Path, required=True)
    b.add_argument("--target", type=Path)
    for sp in (f, b):
        sp.add_argument(
            "--cues",
            choices=tuple(_cue_help()),
            default=None,
            help="fit anew from these observations (default: use SCENE/fit.json "
            "when present, else fit with texture): "
            + "; ".join(f"{k}: {v}" for k, v in _cue_help().items()),
        )
        sp.add_argument(
            "--feet-from-points",
            action="store_true",
            help="turn each foot about its shin at the clicked frame to the heading of the "
            "surface points under it, fitting anew (SCENE/fit.json is not used); off by "
            "default: on the default scene it fixes the right foot's turn but the fit's "
            "joint error as a whole does not gain; needs --cues texture (the default) or "
            "both, as contours give no points",
        )
        sp.add_argument(
            "--smooth",
            action="store_true",
            help="smooth the fitted motion over the take (each joint's path by a Kalman "
            "smoother whose smoothness its likelihood chooses, then the angles solved to it), "
            "fitting anew (SCENE/fit.json is not "
            "used); less jitter on walks and jumps; off by default: a sudden kick of one "
            "limb while the rest of the body is still gets spread over its neighbouring "
            "frames",
        )
        sp.add_argument(
            "--prediction-start-only",
            action="store_true",
            help="fit a frame without texture points (contours alone) from the prediction "
            "only, not also from the previous frame's pose and its extrapolation, fitting "
            "anew (SCENE/fit.json is not used); about half the fit time on a rig without "
            "points, but a fast limb may be lost (the crossing legs of a dance on the "
            "orthogonal rig); off by default, as core fit --prediction-start-only",
        )
        sp.add_argument(
            "--one-pass",
            action="store_true",
            help="fit the motion once, fitting anew (SCENE/fit.json is not used): no late "
            "shape, whose bones the first frames hardly saw are shaped over the fitted take "
            "before a second pass; about half the fit time where a bone qualifies, but "
            "make demo's walk 11.1 -> 12.9 mm; as core fit --one-pass",
        )
        sp.add_argument(
            "--one-flow",
            action="store_true",
            help="fit a take the silhouettes shape (no texture points at the clicked frame, "
            "e.g. the orthogonal rig) that follows the texture flow once, with Lucas-Kanade's "
            "flow corners, fitting anew (SCENE/fit.json is not used); by default it is fitted "
            "a second time with corners refined by least squares matching and the fit the "
            "foregrounds explain better is kept, about twice the fit time there; as core fit "
            "--one-flow",
        )
    for sp in (f, r, b):
        sp.add_argument(
            "--foot-lock",
            action="store_true",
            help="pin the target's feet while in contact (with --target)",
        )
        sp.add_argument(
            "--export",
            choices=("bvh", "fbx"),
            action="append",
            default=[],
            help="also export the motion next to the .blend (repeatable)",
        )
    return p


def _new_file():
    import bpy

    bpy.ops.wm.read_homefile(use_empty=True)


def _save(out: Path):
    import bpy

    out = out.resolve()
    out.parent.mkdir(parents=True, exist_ok=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(out), check_existing=False)
    return out


def _take(state, take, target, out, exports, cameras_from=None, foot_lock=False):
    """Build one take into a fresh file and save it; returns a one-line summary."""
    from . import pipeline, retarget

    _new_file()
    if cameras_from is not None:
        pipeline.create_scene_cameras(cameras_from)
    arm, balls, action = pipeline.build_take(state, take)
    msg = f"{take}: {state.n_frames} frames, action '{action.name}'"
    if target is not None:
        if str(target) == "rigify":
            char = pipeline.generate_rigify_human(f"{take}_rigify", location=(1.0, 0.0, 0.0))
        else:
            char = pipeline.load_character(target)
        res = retarget.retarget(arm, char, take=take, foot_lock=foot_lock)
        msg += f", retargeted {len(res.pairs)} bones onto {char.name}"
        if res.unmapped_target:
            msg += f" (unmapped: {len(res.unmapped_target)} bones)"
    for fmt in exports:
        pipeline.export_motion(arm, out.with_suffix(f".{fmt}"))
    path = _save(out)
    return f"{msg} -> {path}"


def _fit_options(args) -> dict:
    """The keywords of :func:`pipeline.state_for_scene` that ``fit`` and ``batch`` take
    from their flags."""
    return {
        "cues": args.cues or "texture",
        "refit": args.cues is not None,
        "feet_from_points": args.feet_from_points,
        "smooth_motion": args.smooth,
        "contour_starts": not args.prediction_start_only,
        "late_shape": not args.one_pass,
        "flow_choice": not args.one_flow,
    }


def _check_out(out: Path) -> None:
    """Refuse an unusable ``--out`` before the fit's minutes (``_save`` makes its folder)."""
    _core.errors.check_output(out, "the take", ".blend", makes_folder=True)


def cmd_fit(args) -> int:
    from . import pipeline

    _check_out(args.out)
    fresh = [
        name
        for name, on in (
            ("--cues", args.cues is not None),
            ("--feet-from-points", args.feet_from_points),
            ("--smooth", args.smooth),
            ("--prediction-start-only", args.prediction_start_only),
            ("--one-pass", args.one_pass),
            ("--one-flow", args.one_flow),
        )
        if on
    ]
    if args.fit is not None and fresh:
        names = fresh[0] if len(fresh) == 1 else f"{', '.join(fresh[:-1])} and {fresh[-1]}"
        raise _core.errors.InputError(
            f"{args.fit}: --fit uses a fitted state and {names} "
            f"{'asks' if len(fresh) == 1 else 'ask'} for a new fit: give one of them"
        )
    state = pipeline.state_for_scene(
        args.scene, args.fit, _core.progress.Progress(), **_fit_options(args)
    )
    take = args.take or args.scene.resolve().name
    print(
        _take(
            state,
            take,
            args.target,
            args.out,
            args.export,
            cameras_from=args.scene,
            foot_lock=args.foot_lock,
        )
    )
    return 0


def cmd_retarget(args) -> int:
    from . import pipeline

    _check_out(args.out)
    state = pipeline.read_state(args.state)
    take = args.take or args.state.stem
    print(_take(state, take, args.target, args.out, args.export, foot_lock=args.foot_lock))
    return 0


def _takes(folder: Path) -> list[Path]:
    if not folder.is_dir():
        raise _core.errors.InputError(f"{folder}: takes folder not found")
    takes = sorted(
        p
        for p in folder.iterdir()
        if (p.is_dir() and (p / "scene.toml").is_file()) or p.suffix == ".json"
    )
    if not takes:
        raise _core.errors.InputError(f"{folder}: no takes (scene folders or .json states)")
    return takes


def cmd_batch(args) -> int:
    from . import pipeline

    failures = []
    done = 0
    for take in _takes(args.takes):
        out = args.out / f"{take.stem}.blend"
        try:
            if take.is_dir():
                state = pipeline.state_for_scene(
                    take, None, _core.progress.Progress(), **_fit_options(args)
                )
                print(
                    _take(
                        state,
                        take.name,
                        args.target,
                        out,
                        args.export,
                        cameras_from=take,
                        foot_lock=args.foot_lock,
                    )
                )
            else:
                state = pipeline.read_state(take)
                print(
                    _take(state, take.stem, args.target, out, args.export, foot_lock=args.foot_lock)
                )
            done += 1
        except _core.errors.InputError as exc:
            failures.append((take.name, str(exc)))
        except Exception as exc:  # a take must not stop the batch; report it in full
            traceback.print_exc()
            failures.append((take.name, f"{type(exc).__name__}: {exc}"))
        sys.stdout.flush()
    print(f"somacap batch: {done} converted, {len(failures)} failed")
    for name, why in failures:
        print(f"FAILED {name}: {why}", file=sys.stderr)
    return 1 if failures else 0


COMMANDS = {"fit": cmd_fit, "retarget": cmd_retarget, "batch": cmd_batch}


def main(argv: list[str] | None = None) -> int:
    """Entry point for ``blender -c somacap`` and the launcher; returns the exit status."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help or a usage error
        return int(exc.code or 0)
    try:
        return COMMANDS[args.command](args)
    except _core.errors.InputError as exc:
        print(f"somacap: error: {exc}", file=sys.stderr)
        return 2
    except _core.progress.Cancelled:
        print("somacap: cancelled", file=sys.stderr)
        return 130
