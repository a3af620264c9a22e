"""A scene's ground truth expressed as a fitted state (the evaluation's zero point).

The skeleton's rest offsets are measured on the truth's first frame: for each bone,
the vectors from its head joint to the joints it carries are rotated as one rigid set
(Kabsch) to lie as close as possible to the template's directions, so θ = 0 stays an
upright rest pose and the subject's own proportions are kept exactly (s = 1).  Then
per frame the root translation and all joint angles are solved by Levenberg–Marquardt
on the joint positions (analytic Jacobians), each frame started from the previous one.
When the truth is a rigid articulated body with this topology the joints are
reproduced to round-off.  Should some frame not be reproducible (a truth whose
skeleton differs), the state carries the truth joints as ``joints_override`` and the
report says so.

Usage: ``python -m core.truth_state SCENE -o truth_fit.json``.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .landmarks import JOINTS
from .metaballs import make_metaballs
from .skeleton import TEMPLATE_JOINTS, Skeleton, joint_jacobians, make_skeleton
from .state import FitState, Quality

#: Joint reproduction accepted as exact, metres.
EXACT_M = 1e-7


@dataclass
class IKResult:
    """Per-frame IK of joint positions: ``root_xyz (F, 3)``, ``theta (F, n)``,
    ``rmse_m (F,)``, ``max_err_m (F,)``, ``converged (F,)``."""

    root_xyz: np.ndarray
    theta: np.ndarray
    rmse_m: np.ndarray
    max_err_m: np.ndarray
    converged: np.ndarray


def rest_offsets_from(xyz0: np.ndarray, names: list | tuple = JOINTS) -> dict:
    """Rest offsets (joint -> (3,)) measured on one frame of joint positions (J, 3)."""
    idx = {n: i for i, n in enumerate(names)}
    skel = make_skeleton()
    out = {}
    for b, bname in enumerate(skel.bone_names):
        carried = [j for j in JOINTS if TEMPLATE_JOINTS[j][0] == bname and j != "pelvis"]
        if not carried:
            continue
        head = skel.bone_head[b]
        v = np.array([xyz0[idx[j]] - xyz0[idx[head]] for j in carried])  # measured
        t = np.array([TEMPLATE_JOINTS[j][2] for j in carried], dtype=float)
        t = t / np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-12)
        t = t * np.linalg.norm(v, axis=1, keepdims=True)
        R = _kabsch(v, t)
        for j, vv in zip(carried, v, strict=True):
            out[j] = R @ vv
    return out


def _kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation R minimising Σ |R a_i − b_i|² (a, b: (K, 3))."""
    H = a.T @ b
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    return Vt.T @ np.diag([1.0, 1.0, d]) @ U.T


def solve_ik(
    skel: Skeleton,
    target: np.ndarray,
    s: np.ndarray,
    iterations: int = 100,
    theta0: np.ndarray | None = None,
) -> IKResult:
    """Joint angles reproducing target joint positions, frame by frame.

    Parameters
    ----------
    target : (F, J, 3) joint positions in ``skel.joint_names`` order, metres
    s : (G,) scale coefficients (held fixed)
    theta0 : (n,) start of the first frame (default zeros)

    Returns
    -------
    IKResult
    """
    nf = target.shape[0]
    n = skel.n_dof
    pel = skel.joint_index("pelvis")
    th = np.zeros(n) if theta0 is None else np.asarray(theta0, float).copy()
    out_t, out_r = np.zeros((nf, n)), np.zeros((nf, 3))
    rmse, mx, conv = np.zeros(nf), np.zeros(nf), np.zeros(nf, bool)
    for f in range(nf):
        root = target[f, pel] - _root_offset(skel, th, s)
        best = None
        starts = (
            [th] if f > 0 else [th + np.eye(n)[0] * a for a in (0.0, np.pi / 2, -np.pi / 2, np.pi)]
        )
        for start in starts:
            res = _lm(skel, target[f], s, start.copy(), root.copy(), iterations)
            if best is None or res[2] < best[2]:
                best = res
            if best[2] < EXACT_M:
                break
        th, root, err_max, err_rms, ok = best
        out_t[f], out_r[f], rmse[f], mx[f], conv[f] = th, root, err_rms, err_max, ok
    return IKResult(root_xyz=out_r, theta=out_t, rmse_m=rmse, max_err_m=mx, converged=conv)


def _root_offset(skel, theta, s):
    x = joint_jacobians(skel, theta[None], np.zeros((1, 3)), s)[0][0]
    return x[skel.joint_index("pelvis")]


def _lm(skel, target, s, theta, root, iterations):
    """Levenberg–Marquardt on one frame; returns (θ, root, max err, rms err, converged)."""
    n = skel.n_dof
    mu = 1e-3

    def residual(th, rt):
        x, Jt, _ = joint_jacobians(skel, th[None], rt[None], s)
        return (x[0] - target).ravel(), Jt[0].reshape(-1, n)

    r, Jt = residual(theta, root)
    cost = r @ r
    converged = False
    for _ in range(iterations):
        J = np.concatenate([Jt, np.tile(np.eye(3), (len(target), 1))], axis=1)
        A = J.T @ J
        g = J.T @ r
        step = np.linalg.solve(A + mu * np.diag(np.diag(A) + 1e-9), -g)
        th2, rt2 = theta + step[:n], root + step[n:]
        r2, Jt2 = residual(th2, rt2)
        cost2 = r2 @ r2
        if cost2 < cost:
            theta, root, r, Jt = th2, rt2, r2, Jt2
            small = cost - cost2 < 1e-20 or np.sqrt(cost2) < 1e-11
            cost = cost2
            mu = max(mu / 5.0, 1e-12)
            if small:
                converged = True
                break
        else:
            mu *= 4.0
            if mu > 1e8:
                converged = np.sqrt(cost) < 1e-6
                break
    err = np.linalg.norm(r.reshape(-1, 3), axis=-1)
    theta = (theta + np.pi) % (2 * np.pi) - np.pi
    return theta, root, float(err.max()), float(np.sqrt(np.mean(err**2))), converged


def truth_to_state(
    truth: dict, fps: float = 25.0, source_scene: str = "", path: str | Path = "truth.npz"
) -> tuple[FitState, IKResult]:
    """Express a truth dict (``joints_xyz``, ``joint_names``) as a fitted state.

    Returns the state and the IK report.  The state uses ``joints_override`` only if
    some frame could not be reproduced to :data:`EXACT_M`.
    """
    from .evaluate import truth_joints

    xyz, names = truth_joints(truth, path)
    missing = [j for j in JOINTS if j not in names]
    if missing:
        from .errors import InputError

        raise InputError(f"{path}: joint_names lacks {missing} (needs core.landmarks.JOINTS)")
    xyz = xyz[:, [names.index(j) for j in JOINTS]]
    skel = make_skeleton(rest_offsets_from(xyz[0]))
    s = np.ones(skel.n_groups)
    ik = solve_ik(skel, xyz, s)
    q = Quality.empty(xyz.shape[0], skel.n_dof)
    q.rmse_m[:] = ik.rmse_m
    q.converged[:] = ik.converged
    override = None if ik.max_err_m.max() <= EXACT_M else xyz
    state = FitState(
        skeleton=skel,
        s=s,
        metaballs=make_metaballs(skel, "simplified", s),
        root_xyz=ik.root_xyz,
        theta=ik.theta,
        quality=q,
        fps=fps,
        source_scene=source_scene,
        joints_override=override,
    )
    return state, ik


def main(argv: list[str] | None = None) -> int:
    from .errors import InputError
    from .scene import load_scene
    from .state import write_state

    p = argparse.ArgumentParser(
        prog="python -m core.truth_state", description=__doc__.splitlines()[0]
    )
    p.add_argument("scene")
    p.add_argument("-o", "--output", default="truth_fit.json")
    args = p.parse_args(argv)
    try:
        scene = load_scene(args.scene, check_images=False)
        state, ik = truth_to_state(
            scene.truth, scene.fps, str(args.scene), scene.root / "truth.npz"
        )
    except InputError as exc:
        print(f"somacap: error: {exc}", file=sys.stderr)
        return 2
    write_state(args.output, state)
    how = "exact" if state.joints_override is None else "joint positions stored as override"
    print(
        f"wrote {args.output}: {state.n_frames} frames, max joint reproduction error "
        f"{ik.max_err_m.max() * 1000:.2e} mm ({how})"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
