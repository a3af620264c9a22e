"""Command line: ``python -m core {calibrate,track,fit,evaluate} ...``.

Each sub-command lives in the module of its stage and registers itself here through
``COMMANDS`` (name -> "module:function"), imported lazily so that a broken or slow
stage never slows the others.  Bad input raises :class:`~core.errors.InputError`,
printed as one line ``somacap: error: ...`` with exit status 2.  Progress goes to
stderr.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import sys

from .blas_threads import single_blas_thread
from .errors import InputError

#: sub-command -> (module, "add_arguments" function, "run" function, help)
COMMANDS = {
    "calibrate": ("core.calibrate_cli", "Calibrate the cameras from the scene's wand/ sequence"),
    "track": ("core.track_cli", "Measure the surface at frame 0 and track it through the take"),
    "fit": ("core.fit_cli", "Run the whole pipeline and write the fitted state"),
    "evaluate": ("core.evaluate_cli", "Score a fitted state against the scene's truth.npz"),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m core", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    for name, (module, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name != module:
                raise
            p.set_defaults(_missing=module)
            continue
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "_missing", None):
        print(f"somacap: error: '{args.command}' is not available yet", file=sys.stderr)
        return 2
    # track and fit make many small BLAS calls: one OpenBLAS thread spares the busy-waiting
    # of the others (6 fit frames on 2 cores: system CPU 8.8 -> 4.1 s, wall 103 -> 92 s)
    one_thread = args.command in ("track", "fit")
    try:
        with single_blas_thread() if one_thread else contextlib.nullcontext():
            return int(args._run(args) or 0)
    except InputError as exc:
        print(f"somacap: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("somacap: cancelled", file=sys.stderr)
        return 130
