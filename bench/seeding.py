"""Seeding across depth jumps (:mod:`core.surface_seed`) against region growing alone.

``python -m bench.seeding [--scene sample_scenes/walk_line3] [--tracks A.npz B.npz …]``

Frame 0 of a studio scene: the surface grown from the 5 clicked seeds (what ``core
track --no-jump-seeds`` tracks) beside the same plus the points grown from the epipolar
seeds (``core track``'s default) — point counts, distance to the true mesh, and how
many lie on each limb (within 7 cm of the true bone, the hand and foot included).
With ``--tracks``, the points of each ``tracks.npz`` near each limb per frame, and those
more than 2 cm from the true mesh.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from bench.meshtruth import nearest_on_mesh
from core.evaluate import truth_joints
from core.fit_scene import observations_from_tracks
from core.scene import load_scene
from core.surface import concat, measure_surface, seeds_from_clicks
from core.surface_seed import grow_from_jumps

LIMBS = {
    f"{s}_{k}": (f"{s}_{a}", f"{s}_{b}", f"{s}_{c}")
    for s in "lr"
    for k, (a, b, c) in (("arm", ("shoulder", "elbow", "wrist")), ("leg", ("hip", "knee", "ankle")))
}


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    u = np.clip(((p - a) @ ab) / (ab @ ab), 0.0, 1.0)
    return np.linalg.norm(p - (a + u[:, None] * ab), axis=1)


def limb_counts(
    xyz: np.ndarray, joints: np.ndarray, names: list, reach_m: float = 0.07, end_m: float = 0.15
) -> dict:
    """Points (N, 3) within ``reach_m`` of each limb's two bones (the last one extended by
    ``end_m`` for the hand or foot), world metres."""
    out = {}
    for limb, (a, b, c) in LIMBS.items():
        pa, pb, pc = (joints[names.index(j)] for j in (a, b, c))
        pc = pc + end_m * (pc - pb) / np.linalg.norm(pc - pb)
        d = np.minimum(_segment_distance(xyz, pa, pb), _segment_distance(xyz, pb, pc))
        out[limb] = int((d < reach_m).sum())
    return out


def _describe(label: str, xyz: np.ndarray, V: np.ndarray, faces: np.ndarray, joints, names):
    d = nearest_on_mesh(xyz, V, faces)[0]
    limbs = limb_counts(xyz, joints, names)
    print(
        f"  {label:<28} {len(xyz):6d} points, to the true mesh median "
        f"{1000 * np.median(d):.2f} mm, 95th {1000 * np.percentile(d, 95):.1f} mm; "
        + ", ".join(f"{k} {v}" for k, v in limbs.items())
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="sample_scenes/walk_line3")
    ap.add_argument(
        "--tracks", nargs="*", default=[], help="tracks.npz files of the scene to count per frame"
    )
    args = ap.parse_args(argv)
    sc = load_scene(args.scene)
    cams = sc.calibration()
    V, faces = sc.truth["vertices"].astype(float), sc.truth["faces"]
    joints, names = truth_joints(sc.truth)
    imgs = [sc.image(c, 0) for c in sc.cameras]
    t0 = time.perf_counter()
    grown = measure_surface(
        imgs, cams, seeds_from_clicks(sc.clicks(), sc.cameras, 5), max_depth_dev_m=0.01
    )
    t1 = time.perf_counter()
    jump = grow_from_jumps(
        imgs, cams, grown.ref, grown.xyz, grown.uv[:, grown.ref], max_depth_dev_m=0.01
    )
    t2 = time.perf_counter()
    both = grown if jump is None else concat(grown, jump)
    print(f"frame 0 of {args.scene}:")
    _describe(f"growth alone ({t1 - t0:.1f} s)", grown.xyz, V[0], faces, joints[0], names)
    if jump is not None:
        _describe(
            f"epipolar seeds' growth ({t2 - t1:.1f} s)", jump.xyz, V[0], faces, joints[0], names
        )
    _describe("together (core track)", both.xyz, V[0], faces, joints[0], names)
    for path in args.tracks:
        frames = observations_from_tracks(Path(path), sc.n_frames)
        print(f"{path}: points near each limb per frame; points > 2 cm from the true mesh")
        rows = {k: [] for k in LIMBS}
        far = []
        for f, fp in enumerate(frames):
            for k, v in limb_counts(fp.xyz, joints[f], names).items():
                rows[k].append(v)
            far.append(int((nearest_on_mesh(fp.xyz, V[f], faces)[0] > 0.02).sum()))
        for k, v in rows.items():
            print(f"  {k:<6} " + " ".join(f"{x:d}" for x in v))
        print(
            "  far    "
            + " ".join(f"{x:d}" for x in far)
            + f"  (total {sum(far)} of {sum(len(fp.xyz) for fp in frames)} point-frames)"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
