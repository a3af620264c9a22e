"""Texture points of the real-video fit benchmark (:mod:`bench.realvideo_fit`).

The texture-only fit's input: LSM surface points at frame 0, seeded by NCC along
epipolar lines from points between the clicked joints (:data:`SEED_PAIRS`) in the
reference camera (:func:`reference_camera`: of the two fitting cameras closest in
angle), tracked through the take (:func:`texture_tracks`, cached) and turned into
per-frame :class:`core.fit.FramePoints` (:func:`frame_points`).  World Z up, metres;
image points in pixels at the tracking resolution.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from bench.realvideo import epipolar_seeds
from bench.realvideo_inputs import FPS
from core.camera import Camera
from core.errors import InputError

#: Seeds for the LSM surface in the reference camera, as (joint a, joint b, weight of b):
#: points between clicked joints on the back, the buttocks/thighs and the upper arms.
SEED_PAIRS = (
    ("neck", "pelvis", 0.3),
    ("neck", "pelvis", 0.55),
    ("l_shoulder", "r_hip", 0.5),
    ("r_shoulder", "l_hip", 0.5),
    ("l_hip", "l_knee", 0.4),
    ("r_hip", "r_knee", 0.4),
    ("l_shoulder", "l_elbow", 0.4),
    ("r_shoulder", "r_elbow", 0.4),
    ("l_knee", "l_ankle", 0.35),
    ("r_knee", "r_ankle", 0.35),
)


def texture_tracks(
    grey: dict,
    cams: list[Camera],
    clicks: dict,
    n_frames: int,
    scale: float,
    cache: Path,
    ref: int = 1,
):
    """LSM surface points at frame 0 tracked through ``n_frames`` (cached in ``cache``).

    Returns ``(xyz (F, P, 3) metres, sigma_xyz (F, P, 3) metres, info dict)``.
    """
    names = [c.name for c in cams]
    key = f"{','.join(names)}|{n_frames}|{scale}|{ref}"
    if cache.is_file():
        with np.load(cache, allow_pickle=False) as z:
            if str(z["key"]) == key:
                return z["xyz"], z["sigma_xyz"], json.loads(str(z["info"]))
    from core.lsm import ImageStack
    from core.surface import measure_surface
    from core.tracking import track

    t0 = time.perf_counter()
    j = clicks["joints"]
    ref_name = names[ref]
    uv_ref = np.array(
        [
            (1 - w) * j[a][ref_name] + w * j[b][ref_name]
            for a, b, w in SEED_PAIRS
            if ref_name in j.get(a, {}) and ref_name in j.get(b, {})
        ]
    )
    uv_ref = (uv_ref + 0.5) * scale - 0.5
    st0 = ImageStack([grey[n][0] for n in names])
    seeds = epipolar_seeds(st0, cams, ref, uv_ref)
    if len(seeds) == 0:
        raise InputError("no LSM seed matched along the epipolar lines")
    surf = measure_surface(st0, cams, seeds, ref=ref, step=2)
    t1 = time.perf_counter()
    tr = track(
        lambda i: [grey[n][i] for n in names], cams, surf, n_frames, FPS, step=2, regen_every=5
    )
    t2 = time.perf_counter()
    alive = tr.alive
    info = {
        "seeds": int(len(seeds)),
        "seed_candidates": int(len(uv_ref)),
        "surface_points": int(len(surf)),
        "surface_s": t1 - t0,
        "tracking_s": t2 - t1,
        "alive_per_frame_median": float(np.median(alive.sum(axis=1))),
        "frame0_through": int(alive[:, : len(surf)].all(axis=0).sum()),
        "trajectories": int(tr.xyz.shape[1]),
    }
    cache.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(cache, xyz=tr.xyz, sigma_xyz=tr.sigma_xyz, key=key, info=json.dumps(info))
    return tr.xyz, tr.sigma_xyz, info


def frame_points(xyz: np.ndarray, sigma_xyz: np.ndarray):
    """Per-frame :class:`core.fit.FramePoints` from tracks (trajectory index as id)."""
    from core.fit import FramePoints

    sig = np.sqrt(np.mean(sigma_xyz**2, axis=2))
    sig = np.where(np.isfinite(sig) & (sig > 0), sig, 0.005)
    ids = np.arange(xyz.shape[1])
    out = []
    for f in range(len(xyz)):
        ok = np.all(np.isfinite(xyz[f]), axis=1)
        out.append(FramePoints(xyz=xyz[f, ok], sigma=sig[f, ok], ids=ids[ok]))
    return out


def reference_camera(cams: list[Camera]) -> int:
    """The reference camera for LSM: one of the two fitting cameras whose optical axes
    are closest in angle (LSM needs similar views; the other cameras join by NCC)."""
    best, ref = -2.0, 0
    for i in range(len(cams)):
        for j in range(i + 1, len(cams)):
            c = float(cams[i].R[2] @ cams[j].R[2])
            if c > best:
                best, ref = c, i
    return ref
