"""Arm swing in gait: a hidden arm swings against the opposite thigh.

In walking each arm swings forward with the opposite leg.  Where an arm is behind the
trunk in every camera for a stretch of a walk (its angles *unobserved*,
:func:`core.fit_bridge.unobserved`) and nothing better placed it — the per-angle
coupling of :mod:`core.fit_coupling` needs the arm seen over much of its swing, and the
mirror of :mod:`core.fit_mirror` is for movements where the legs move alike — the
bridge interpolates its angles between the frames around the stretch.  That cannot
follow a swing that goes back and returns within the stretch.

:func:`gait_swing_arms` moves such an arm by the change of the opposite thigh's swing
times a fixed ratio, measured from the stretch's observed ends.  A segment's *swing*
(:func:`sagittal_swings`) is its angle in the body's sagittal plane, forward positive:
the upper arm's in the trunk's frame (shoulders and neck), the thigh's in the pelvis's
frame (hips and spine).  Within a stretch the arm's swing is predicted as

    φ(t) = ``ratio`` · d(t) + r(t)

with d the opposite thigh's swing and r the residual ``φ − ratio·d`` of the observed
frames at the stretch's ends, interpolated across (held from the one observed end of a
stretch that reaches the first or last frame).  The upper arm is then turned about the
trunk's left–right axis by the difference between that swing and the one it had,
its twist kept, and the shoulder's three angles solved for that orientation within
their limits; the elbow and the wrist keep their angles.

The ratio is taken from the gait literature, not from the subject: each arm swings
through about 30° per stride (Perry & Burnfield, *Gait Analysis*, ch. 8; 24.6 ± 2.4°
in ten men measured with Vicon) while the hip flexes and extends through about 40°, a
ratio of 0.6–0.75; the default is 0.7.  Fitting the ratio to the frames where the
hidden arm was seen does not work: it is seen in one half of its swing, where the thigh
is near its extreme, and that slope is ill-determined.

It applies only to gait.  The thighs' swings must move against each other: their
correlation over the fitted frames ≤ ``max_legs_r`` (−0.5; make demo's walk gives
−0.69 to −0.87 over the click draws, a jump +1.0), each with a standard deviation
≥ ``min_thigh_deg``.  And the other arm, where it was seen (at least 10 frames), must
swing with its own opposite thigh: least-squares slope ≥ ``min_other_ratio`` (0.15;
make demo's walk 0.33–0.46 over the click draws).  Legs pedalling a bicycle move
against each other too, but the hands stay on the handlebar.

On make demo's walk (the right arm behind the trunk in frames 8–23 and 35–49), the
four fits of ``bench.fit_spread --runs 4`` (run 0 the exact clicks): MPJPE 12.46 /
13.51 / 13.56 / 15.64 → 9.71 / 13.13 / 13.36 / 14.30 mm, median 13.53 → 13.25; run 0's
right wrist 56 → 26 mm.  The jumps are not gait and do not change; walk_ortho3 14.21 →
14.22 mm.  The ratio's sensitivity is in ``docs/design.md`` ("The hidden arm's swing
in a walk").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from .fit_bridge import fill_runs
from .skeleton import Skeleton, bone_frames, forward, joint_positions

#: the shoulder's DOF axes (``r_shoulder_x`` …) that the swing solves for
SHOULDER_AXES = ("x", "y", "z")


@dataclass
class GaitSwing:
    """What :func:`gait_swing_arms` did for one arm.

    Attributes
    ----------
    limb : ``"r_arm"`` or ``"l_arm"``
    legs_r : float, correlation of the two thighs' swings over the fitted frames
    other_ratio : float, the other arm's swing per degree of its opposite thigh's where
        it was seen (NaN when seen in fewer than 10 frames)
    frames : int, frames whose shoulder angles were replaced
    """

    limb: str
    legs_r: float
    other_ratio: float
    frames: int


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def _plane(lateral: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(lateral, up, forward) unit axes (F, 3): ``up`` made orthogonal to ``lateral``,
    forward = lateral × up (the subject's left × up is the way the subject faces)."""
    lat = _unit(lateral)
    up = _unit(up - np.sum(up * lat, axis=-1, keepdims=True) * lat)
    return lat, up, np.cross(lat, up)


def body_axes(x: np.ndarray, names: tuple | list) -> dict:
    """The pelvis's and the trunk's axes from joint positions.

    Parameters
    ----------
    x : (F, J, 3) joint positions, metres; names : the J joint names (the skeleton's)

    Returns
    -------
    dict with ``"pelvis"`` and ``"trunk"``: each (lateral, up, forward), (F, 3) unit
    vectors.  Lateral points to the subject's left (hips, resp. shoulders), up from the
    pelvis to the spine (resp. from the mid-hips to the neck), forward = lateral × up.
    """
    j = {n: x[:, i] for i, n in enumerate(names)}
    mid_hips = 0.5 * (j["l_hip"] + j["r_hip"])
    return {
        "pelvis": _plane(j["l_hip"] - j["r_hip"], j["spine"] - j["pelvis"]),
        "trunk": _plane(j["l_shoulder"] - j["r_shoulder"], j["neck"] - mid_hips),
    }


def swing_deg(v: np.ndarray, up: np.ndarray, fwd: np.ndarray) -> np.ndarray:
    """(F,) angle of the segment vectors ``v`` (F, 3) from straight down, forward
    positive, in the plane of ``up`` and ``fwd``, degrees."""
    return np.degrees(np.arctan2(np.sum(v * fwd, axis=-1), -np.sum(v * up, axis=-1)))


def sagittal_swings(x: np.ndarray, names: tuple | list) -> dict:
    """Sagittal swings (F,) in degrees of the upper arms (``"l_arm"``, ``"r_arm"``, in
    the trunk's frame) and the thighs (``"l_thigh"``, ``"r_thigh"``, in the pelvis's).

    Parameters
    ----------
    x : (F, J, 3) joint positions, metres; names : the J joint names
    """
    ax = body_axes(x, names)
    j = {n: x[:, i] for i, n in enumerate(names)}
    _, up_t, fwd_t = ax["trunk"]
    _, up_p, fwd_p = ax["pelvis"]
    out = {}
    for side in "lr":
        out[f"{side}_arm"] = swing_deg(j[f"{side}_elbow"] - j[f"{side}_shoulder"], up_t, fwd_t)
        out[f"{side}_thigh"] = swing_deg(j[f"{side}_knee"] - j[f"{side}_hip"], up_p, fwd_p)
    return out


def _rotation(axis: np.ndarray, deg: float) -> np.ndarray:
    """3 × 3 rotation by ``deg`` degrees about the unit ``axis`` (Rodrigues)."""
    a = np.radians(deg)
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + np.sin(a) * k + (1.0 - np.cos(a)) * (k @ k)


def turn_bone(
    skel: Skeleton,
    theta: np.ndarray,
    root_xyz: np.ndarray,
    s: np.ndarray,
    bone: str,
    dofs: np.ndarray,
    turn: np.ndarray,
) -> np.ndarray:
    """Angles of ``dofs`` that turn ``bone``'s world orientation by ``turn``.

    Parameters
    ----------
    theta : (n,) one frame's angles, radians; root_xyz : (3,) metres; s : (G,) scales
    bone : the bone to turn; dofs : (k,) int, its own DOFs (the ones solved)
    turn : (3, 3) world rotation applied to the bone's current orientation

    Returns
    -------
    (k,) angles, radians, within the DOFs' limits: the least-squares fit of the bone's
    rotation matrix to the turned one (exact where the limits allow).
    """
    b = skel.bone_index(bone)
    R0, _ = bone_frames(skel, forward(skel, theta, root_xyz, s))
    target = turn @ R0[0, b]
    lo, hi = skel.dof_lo[dofs], skel.dof_hi[dofs]
    lo = np.where(np.isfinite(lo), lo, -np.inf)
    hi = np.where(np.isfinite(hi), hi, np.inf)
    x0 = np.clip(theta[dofs], lo, hi)

    def resid(x):
        t = np.array(theta, float)
        t[dofs] = x
        R, _ = bone_frames(skel, forward(skel, t, root_xyz, s))
        return (R[0, b] - target).ravel()

    return least_squares(resid, x0, bounds=(lo, hi), xtol=1e-10, ftol=1e-10).x


def gait_swing_arms(
    skel: Skeleton,
    theta: np.ndarray,
    root_xyz: np.ndarray,
    s: np.ndarray,
    unobserved: np.ndarray,
    replace: np.ndarray,
    diverged: np.ndarray | None = None,
    ratio: float = 0.7,
    max_legs_r: float = -0.5,
    min_thigh_deg: float = 5.0,
    min_other_ratio: float = 0.15,
) -> tuple[np.ndarray, np.ndarray, list[GaitSwing]]:
    """Swing hidden arms with the opposite thigh in a walk (see the module text).

    Parameters
    ----------
    theta : (F, n) fitted angles, radians (the hidden arms held or bridged)
    root_xyz : (F, 3) metres; s : (G,) bone scales
    unobserved : (F, n) bool, angles whose parts were hidden in every camera
    replace : (F, n) bool, the unobserved angles this may replace (not those the
        coupling or the mirror placed)
    diverged : (F,) bool, frames that are only a prediction
    ratio : the arm's swing change per degree of the opposite thigh's
    max_legs_r : the thighs' swings must correlate at most this much (gait)
    min_thigh_deg : ... and each vary by at least this standard deviation, degrees
    min_other_ratio : the other arm's least-squares swing per degree of its opposite
        thigh's, over the frames it was seen, must be at least this

    Returns
    -------
    theta : (F, n) a copy with the swung frames' shoulder angles replaced
    swung : (F, n) bool, the angles replaced
    report : one :class:`GaitSwing` per arm that had frames to replace
    """
    theta = np.array(theta, float)
    root_xyz = np.asarray(root_xyz, float)
    unobs = np.asarray(unobserved, bool)
    repl = np.asarray(replace, bool) & unobs
    nf = len(theta)
    div = np.zeros(nf, bool) if diverged is None else np.asarray(diverged, bool)
    swung = np.zeros_like(unobs)
    report: list[GaitSwing] = []
    names = skel.joint_names
    x = joint_positions(skel, theta, root_xyz, s)
    sw = sagittal_swings(x, names)
    thigh_ok = {
        side: ~unobs[:, [skel.dof_index(f"{side}_hip_{a}") for a in "xyz"]].any(axis=1) & ~div
        for side in "lr"
    }
    legs = thigh_ok["l"] & thigh_ok["r"]
    if legs.sum() < 10:
        return theta, swung, report
    dl, dr = sw["l_thigh"][legs], sw["r_thigh"][legs]
    if min(dl.std(), dr.std()) < min_thigh_deg:
        return theta, swung, report
    legs_r = float(np.corrcoef(dl, dr)[0, 1])
    # a turn about the trunk's right-pointing axis (−lateral) tips "down" forwards
    trunk_right = -body_axes(x, names)["trunk"][0]
    for side, other in (("r", "l"), ("l", "r")):
        dofs = np.array([skel.dof_index(f"{side}_shoulder_{a}") for a in SHOULDER_AXES])
        run = repl[:, dofs].any(axis=1) & ~div & thigh_ok[other]
        if not run.any():
            continue
        other_dofs = [skel.dof_index(f"{other}_shoulder_{a}") for a in SHOULDER_AXES]
        other_seen = ~unobs[:, other_dofs].any(axis=1) & ~div & thigh_ok[side]
        other_ratio = np.nan
        if other_seen.sum() >= 10:
            other_ratio = float(
                np.polyfit(sw[f"{side}_thigh"][other_seen], sw[f"{other}_arm"][other_seen], 1)[0]
            )
        if legs_r > max_legs_r or not other_ratio >= min_other_ratio:
            report.append(GaitSwing(f"{side}_arm", legs_r, other_ratio, 0))
            continue
        seen = ~unobs[:, dofs].any(axis=1) & ~div
        phi, d = sw[f"{side}_arm"], sw[f"{other}_thigh"]
        target = phi.copy()
        done = fill_runs(target, ratio * d, run, seen, ends=True)
        for f in np.flatnonzero(done):
            turn = _rotation(trunk_right[f], float(target[f] - phi[f]))
            theta[f, dofs] = turn_bone(
                skel, theta[f], root_xyz[f], s, f"{side}_shoulder", dofs, turn
            )
        swung[np.ix_(done, dofs)] = True
        report.append(GaitSwing(f"{side}_arm", legs_r, other_ratio, int(done.sum())))
    return theta, swung, report
