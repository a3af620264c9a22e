"""``python -m core track SCENE -o tracks.npz``: surface at frame 0, then tracking.

Arrays written to the ``.npz`` (F frames, P points, C cameras):

* ``xyz`` (F, P, 3) float — filtered 3-D trajectories, world metres, NaN where not tracked
* ``xyz_raw`` (F, P, 3) float — trajectories before the filters
* ``uv`` (F, P, C, 2) float — image points, pixels, NaN where not matched
* ``sigma_xyz`` (F, P, 3) float — standard deviations from the forward intersection, m
* ``start`` (P,) int — first frame of each trajectory (0 = measured at frame 0)
* ``measured`` (F, P) bool — measured by forward intersection in that frame (False
  where a gap was bridged after a re-acquisition, see ``--max-dormant`` and
  ``--max-coast``, or not tracked)
* ``removed`` (P,) bool, ``truncated`` (P,) bool — outcome of the filters
* ``camera_names`` (C,) str, ``fps`` () float
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from .errors import InputError, check_output
from .progress import Progress
from .scene import load_scene
from .surface import concat, measure_surface, seeds_from_clicks
from .surface_pairs import grow_pairs
from .surface_seed import grow_from_jumps
from .track_settings import TrackSettings
from .tracking import filter_trajectories, track


def add_arguments(parser) -> None:
    parser.add_argument("scene", help="scene folder")
    parser.add_argument("-o", "--output", required=True, help="output .npz")
    parser.add_argument("--frames", type=int, default=None, help="track only the first N frames")
    parser.add_argument("--seeds", type=int, default=5, help="seed joints from clicks.json")
    parser.add_argument("--step", type=int, default=2, help="surface grid step, pixels")
    parser.add_argument(
        "--regen-every",
        type=int,
        default=None,
        help="regenerate points every N frames (0: never; default: "
        "core.track_settings.TrackSettings's, 3)",
    )
    parser.add_argument(
        "--predict",
        choices=("ekf", "linear"),
        default="ekf",
        help="search prediction: 3-D Kalman filter or 2-D linear",
    )
    parser.add_argument(
        "--max-coast",
        type=int,
        default=None,
        help="frames a point may coast on its neighbours' motion and be "
        "measured again (default: core.tracking.track's)",
    )
    parser.add_argument(
        "--max-dormant",
        type=int,
        default=None,
        help="frames a lost point stays dormant and may be re-acquired "
        "from its key templates (0: never)",
    )
    parser.add_argument(
        "--no-anchor",
        action="store_true",
        help="no re-anchoring of temporal matches on key templates",
    )
    parser.add_argument(
        "--no-jump-seeds",
        action="store_true",
        help="do not seed surface beyond the depth jumps that region growing "
        "stops at (a limb beside or behind the trunk; core.surface_seed)"
        " at frame 0 and when regenerating",
    )
    parser.add_argument(
        "--pair-seeds",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="also measure the surface that the reference (middle) camera does not "
        "see from pairs of the other cameras (core.surface_pairs), at frame 0 and "
        "when regenerating (default: core.track_settings.TrackSettings's)",
    )


def run(args) -> int:
    out = check_output(args.output, "the tracks", ".npz")
    scene = load_scene(args.scene)
    cams = scene.calibration()
    if len(cams) < 2:
        raise InputError(f"{scene.root}/scene.toml: tracking needs two or more cameras")
    n = scene.n_frames if args.frames is None else min(args.frames, scene.n_frames)
    if n < 1:
        raise InputError(f"--frames must be positive, got {args.frames}")
    progress = Progress()
    seeds = seeds_from_clicks(
        scene.clicks(), scene.cameras, args.seeds, path=scene.root / "clicks.json"
    )
    t0 = time.perf_counter()
    first = [scene.image(c, 0) for c in scene.cameras]
    surf = measure_surface(
        first, cams, seeds, step=args.step, progress=progress, max_depth_dev_m=0.01
    )  # as track()'s depth_dev_m
    if not args.no_jump_seeds:
        jump = grow_from_jumps(
            first,
            cams,
            surf.ref,
            surf.xyz,
            surf.uv[:, surf.ref],
            step=args.step,
            max_depth_dev_m=0.01,
        )
        if jump is not None and len(jump):  # a limb the growth did not reach from the seeds
            surf = concat(surf, jump)
    pair_seeds = TrackSettings().pair_seeds if args.pair_seeds is None else args.pair_seeds
    if pair_seeds and len(cams) > 2:  # a limb the reference camera does not see
        occupied = [surf.uv[:, j] for j in range(len(cams))]
        surf = concat(surf, grow_pairs(first, cams, surf.ref, surf.xyz, occupied, step=args.step))
    print(
        f"surface: {len(surf)} points at frame 0 ({time.perf_counter() - t0:.1f} s)",
        file=sys.stderr,
    )
    t1 = time.perf_counter()
    tr = track(
        lambda i: [scene.image(c, i) for c in scene.cameras],
        cams,
        surf,
        n,
        scene.fps,
        step=args.step,
        predict=args.predict,
        anchor=not args.no_anchor,
        jump_seeds=not args.no_jump_seeds,
        pair_seeds=pair_seeds,
        progress=progress,
        **({} if args.regen_every is None else {"regen_every": args.regen_every}),
        **({} if args.max_dormant is None else {"max_dormant": args.max_dormant}),
        **({} if args.max_coast is None else {"max_coast": args.max_coast}),
    )
    dt = time.perf_counter() - t1
    flt = filter_trajectories(tr.xyz, scene.fps)
    np.savez_compressed(
        out,
        xyz=flt.xyz,
        xyz_raw=tr.xyz,
        uv=tr.uv,
        sigma_xyz=tr.sigma_xyz,
        start=tr.start,
        measured=tr.measured,
        removed=flt.removed,
        truncated=flt.truncated,
        camera_names=np.array(scene.cameras),
        fps=np.float64(scene.fps),
    )
    alive = np.all(np.isfinite(flt.xyz), axis=2)
    print(
        f"tracked {n} frames at {(n - 1) / max(dt, 1e-9):.2f} frames/s; "
        f"{tr.xyz.shape[1]} trajectories, {int(alive[-1].sum())} live at the last frame, "
        f"{int(flt.removed.sum())} removed by the filters -> {out}",
        file=sys.stderr,
    )
    return 0
