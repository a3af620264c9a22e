"""Functional joint centres from the tracked points, against the clicks' depth.

``python -m bench.joint_centres [SCENE] [--runs N] [--click-noise PX]``

On ``line3`` a clicked joint is 12–13 mm uncertain along the cameras' common view per
pixel of clicking error, and the fit keeps that error in every frame (``docs/design.md``,
"A click's error in depth stays in every frame").  Biomechanics places a joint without
clicks from the motion of its two segments: the centre is the one point that moves
rigidly with both (SCoRE, Ehrig et al. 2006, J. Biomech. 39:2798).  This benchmark asks
whether that point, estimated from the tracked trajectories, would fix a click's depth.

For each of the joints of :data:`JOINTS`, the points tracked at the clicked frame are
labelled to the segment they lie nearest (bones between the clicked joints; points near
either end left out), each segment's rigid motion from the clicked frame to every other
frame is taken from its points (Kabsch), and the centre solves
``R_a(t) x + t_a(t) = R_b(t) x + t_b(t)`` over the frames by least squares.  It prints,
per run (run 0 the clicks as they are, runs 1… moved by N(0, PX²) as in
:mod:`bench.fit_spread`): the clicked point's error against the truth (and its part
along the click's least-certain axis), the functional centre's, and the angle between
that axis and the functional solve's least-determined direction — for a hinge, the
hinge's own axis, along which no motion of the two segments tells where the joint is.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

#: joint: (proximal segment, distal segment), each segment by its two clicked end joints
JOINTS = {
    "l_knee": (("l_hip", "l_knee"), ("l_knee", "l_ankle")),
    "r_knee": (("r_hip", "r_knee"), ("r_knee", "r_ankle")),
    "l_elbow": (("l_shoulder", "l_elbow"), ("l_elbow", "l_wrist")),
    "r_elbow": (("r_shoulder", "r_elbow"), ("r_elbow", "r_wrist")),
}


def rigid_motion(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """The rotation ``R`` (3, 3) and translation ``t`` (3,) taking points ``a`` (N, 3)
    onto ``b`` (N, 3) in the least-squares sense (Kabsch), and the RMS residual, in the
    points' units."""
    ma, mb = a.mean(0), b.mean(0)
    u, _, vt = np.linalg.svd((a - ma).T @ (b - mb))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    t = mb - r @ ma
    rms = float(np.sqrt(np.mean(np.sum((a @ r.T + t - b) ** 2, axis=1))))
    return r, t, rms


def functional_centre(
    ref_a: np.ndarray,
    ref_b: np.ndarray,
    frames_a: list,
    frames_b: list,
    min_points: int = 6,
) -> tuple[np.ndarray, np.ndarray]:
    """The point that moves rigidly with two segments (SCoRE).

    Parameters
    ----------
    ref_a, ref_b : (Na, 3), (Nb, 3) the two segments' points in the reference frame
    frames_a, frames_b : per other frame, ``(index (n,), xyz (n, 3))`` — which of the
      segment's points were seen in that frame and where; frames with fewer than
      ``min_points`` of either segment are skipped

    Returns
    -------
    centre : (3,) in the reference frame's coordinates (NaN if under two frames)
    normal : (3, 3) the normal matrix ``Σ (R_a − R_b)ᵀ (R_a − R_b)``; its eigenvector of
      the smallest eigenvalue is the direction the motion leaves least determined (the
      axis of a hinge)
    """
    rows, rhs = [], []
    for (ia, xa), (ib, xb) in zip(frames_a, frames_b, strict=True):
        if len(ia) < min_points or len(ib) < min_points:
            continue
        ra, ta, _ = rigid_motion(ref_a[ia], xa)
        rb, tb, _ = rigid_motion(ref_b[ib], xb)
        rows.append(ra - rb)
        rhs.append(tb - ta)
    if len(rows) < 2:
        return np.full(3, np.nan), np.zeros((3, 3))
    a, b = np.concatenate(rows), np.concatenate(rhs)
    return np.linalg.lstsq(a, b, rcond=None)[0], a.T @ a


def segment_points(
    xyz: np.ndarray, segments: dict, ends: tuple = (0.2, 0.8), reach_m: float = 0.12
) -> dict:
    """Indices of the points (N, 3) that lie nearest each segment ``{name: (a, b)}`` (two
    (3,) end points, metres), within ``reach_m`` of it and between the fractions ``ends``
    of its length (points near a joint move with both segments)."""
    names = list(segments)
    dist = np.empty((len(names), len(xyz)))
    frac = np.empty_like(dist)
    for k, n in enumerate(names):
        a, b = segments[n]
        ab = b - a
        u = np.clip(((xyz - a) @ ab) / (ab @ ab), 0.0, 1.0)
        dist[k] = np.linalg.norm(xyz - (a + u[:, None] * ab), axis=1)
        frac[k] = u
    near = np.argmin(dist, axis=0)
    out = {}
    for k, n in enumerate(names):
        keep = (near == k) & (dist[k] < reach_m) & (frac[k] > ends[0]) & (frac[k] < ends[1])
        out[n] = np.flatnonzero(keep)
    return out


def run(scene_dir: Path, tracks: Path, noise_px: float, seed: int) -> list[dict]:
    """Each joint of :data:`JOINTS`: its click's and its functional centre's errors."""
    from bench.fit_spread import perturbed_clicks
    from core.evaluate import truth_joints
    from core.fit_init import triangulate_clicks
    from core.scene import load_scene

    scene = load_scene(scene_dir, check_images=False)
    clicks = perturbed_clicks(scene.clicks(), noise_px, seed)
    cp = triangulate_clicks(clicks, scene.calibration())
    at = dict(zip(cp.names, cp.xyz, strict=True))
    truth, names = truth_joints(scene.truth)
    f0 = clicks["frame"]
    tr = np.load(tracks)
    seen = tr["measured"] & ~tr["removed"][None] & np.isfinite(tr["xyz"]).all(-1)
    xyz = tr["xyz"]
    idx0 = np.flatnonzero(seen[f0])
    segments = {
        f"{a}-{b}": (at[a], at[b])
        for pair in JOINTS.values()
        for a, b in pair
        if a in at and b in at
    }
    segments["trunk"] = ((at["l_hip"] + at["r_hip"]) / 2, at["neck"])
    members = {n: idx0[i] for n, i in segment_points(xyz[f0, idx0], segments).items()}
    out = []
    for joint, (pa, pb) in JOINTS.items():
        na, nb = f"{pa[0]}-{pa[1]}", f"{pb[0]}-{pb[1]}"
        if joint not in at or min(len(members.get(na, ())), len(members.get(nb, ()))) < 6:
            continue  # a segment without tracked points (hidden from the cameras)
        fa, fb = [], []
        for f in range(len(xyz)):
            if f == f0:
                continue
            for ids, acc in ((members[na], fa), (members[nb], fb)):
                on = np.flatnonzero(seen[f, ids])
                acc.append((on, xyz[f, ids[on]]))
        centre, normal = functional_centre(xyz[f0, members[na]], xyz[f0, members[nb]], fa, fb)
        k = cp.names.index(joint)
        depth = np.linalg.eigh(cp.cov[k])[1][:, 2]
        weak = np.linalg.eigh(normal)[1][:, 0]
        t = truth[f0, names.index(joint)]
        out.append(
            {
                "joint": joint,
                "points": (len(members[na]), len(members[nb])),
                "click_mm": 1000 * float(np.linalg.norm(at[joint] - t)),
                "click_depth_mm": 1000 * float(abs(depth @ (at[joint] - t))),
                "centre_mm": 1000 * float(np.linalg.norm(centre - t)),
                "centre_depth_mm": 1000 * float(abs(depth @ (centre - t))),
                "weak_vs_depth_deg": float(np.degrees(np.arccos(min(1.0, abs(weak @ depth))))),
            }
        )
    return out


def main(argv: list[str] | None = None) -> int:
    from bench.fit import RENDERS, _resolve
    from bench.fit_spread import scene_tracks

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?", default="sample_scenes/walk_line3")
    ap.add_argument("--runs", type=int, default=4)
    ap.add_argument("--click-noise", type=float, default=0.5)
    args = ap.parse_args(argv)
    scene, _ = _resolve(args.scene, RENDERS)
    tracks = scene_tracks(scene)
    print(
        f"{scene.name}: joint centres at the clicked frame against the truth, mm "
        "(total / along the click's least-certain axis)"
    )
    print(
        f"{'run':>3} {'joint':<8} {'points':>9} {'click':>13} {'functional':>13}"
        f" {'hinge∠depth':>12}"
    )
    for seed in range(args.runs):
        for r in run(scene, tracks, args.click_noise, seed):
            pts = f"{r['points'][0]}/{r['points'][1]}"
            print(
                f"{seed:3d} {r['joint']:<8} {pts:>9} "
                f"{r['click_mm']:6.1f} /{r['click_depth_mm']:5.1f} "
                f"{r['centre_mm']:6.1f} /{r['centre_depth_mm']:5.1f} "
                f"{r['weak_vs_depth_deg']:10.0f}°"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
