"""``python -m core calibrate SCENE [-o calibration.toml]``: calibrate from the wand."""

from __future__ import annotations

import argparse
from pathlib import Path

from .bundle import DEFAULT_FREE
from .calibration_io import read_calibration, write_calibration
from .camera import INTRINSIC_NAMES
from .errors import InputError, check_output
from .progress import Progress


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", type=Path, help="scene folder with wand/ and wand.toml")
    parser.add_argument(
        "-o",
        "--output",
        type=Path,
        default=None,
        help="output calibration.toml (default: SCENE/calibration.toml, "
        "which is never replaced unless --force)",
    )
    parser.add_argument("--force", action="store_true", help="replace an existing output file")
    parser.add_argument(
        "--free",
        default=None,
        help="comma-separated free interior parameters, of "
        f"{','.join(INTRINSIC_NAMES)} (default "
        f"{','.join(DEFAULT_FREE)}, plus aspect for single fields)",
    )
    parser.add_argument(
        "--no-z-up",
        dest="z_up",
        action="store_false",
        help="keep the adjustment's world (camera 1's frame) instead of "
        "the Z-up world (mean camera up = +Z, origin at the wand "
        "volume's centroid dropped to its lowest position)",
    )
    parser.add_argument(
        "--reference",
        type=Path,
        default=None,
        help="compare with this calibration (e.g. the truth) after a similarity alignment",
    )


def run(args: argparse.Namespace) -> int:
    from .calibrate import calibrate_scene, compare_to_reference
    from .scene import load_wand

    out = check_output(
        args.output if args.output is not None else args.scene / "calibration.toml",
        "the calibration",
        makes_folder=True,  # write_calibration creates it
    )
    if out.exists() and not args.force:
        raise InputError(
            f"{out}: exists already; pass -o with another file or --force to replace it"
        )
    free = None
    if args.free:
        free = tuple(p.strip() for p in args.free.split(",") if p.strip())
        bad = [p for p in free if p not in INTRINSIC_NAMES]
        if bad:
            raise InputError(
                f"--free: unknown interior parameter '{bad[0]}' (choose from "
                f"{', '.join(INTRINSIC_NAMES)})"
            )
    reference = read_calibration(args.reference) if args.reference is not None else None
    scene = load_wand(args.scene)
    if reference is not None and len(reference) != len(scene.cameras):
        raise InputError(
            f"{args.reference}: has {len(reference)} cameras but the scene has "
            f"{len(scene.cameras)}: the camera counts must match"
        )
    report = calibrate_scene(scene, free=free, progress=Progress(), z_up=args.z_up)
    print(report.text())
    if reference is not None:
        cmp = compare_to_reference(report.cameras, reference, str(args.reference))
        print(f"\nagainst {args.reference} (similarity aligned, scale {cmp['scale']:.5f}):")
        for c, e, fe in zip(report.cameras, cmp["centre_error_m"], cmp["focal_error"], strict=True):
            print(f"  {c.name:8s} centre error {e * 1e3:7.3f} mm   focal error {100 * fe:+.4f} %")
    write_calibration(out, report.cameras, report.metadata(), overwrite=True)
    print(f"\nwrote {out}")
    return 0 if report.bundle.success else 1
