"""Mirrored arms: a hidden arm predicted from the other arm while the legs move alike.

Where one arm has no observation of its own (its parts *hidden*, :mod:`core.fit`) and
no coupling to the opposite thigh could be learnt (:mod:`core.fit_coupling`: it needs
frames where the arm was seen), the fit can only hold its angles.  In a bilateral
movement — a jump, a squat, a lift — both arms do the same, mirrored.  The legs, which
the cameras see, tell whether the movement is bilateral: when over a hidden stretch
(``margin`` frames beyond it on each side) the right leg's sagittal angles (hip and
knee flexion) are the left leg's mirrored, explaining at least ``r2_min`` of their
variance, and the legs do move (their standard deviation ≥ ``min_motion``), the hidden
arm takes the observed arm's angles, mirrored (:func:`mirror_pairs`).  At an observed
end of the stretch, and at the clicked frame, the fitted angle's offset from the mirror
image is kept and fades out over ``blend`` frames.  In a walk the legs swing against
each other (R² < 0 on make demo's walk and walk_ortho3), and nothing is mirrored.

On jumps_line3 (CMU 01_01, forward jumps, line3) the right arm is behind the body in
all three cameras in every frame; only the hand is seen, in frames 35–46.  The legs
move mirrored at R² 0.93; on the truth the mirrored left elbow and wrist lie 22 and 36
mm from the right ones on average.  Mirroring the fitted left arm (in-process on the
scene's tracks, cues both): MPJPE 20.33 → 14.17 mm, right elbow 60 → 28 mm, right
wrist 96 → 43 mm, limb segments 11.7° → 7.0° (14.43 mm without the clicked frame as an
anchor).  Anchoring the shoulder and elbow at the frames where only the hand was seen
(the unobserved-angle rule of :mod:`core.fit_bridge`) kept them 75–89 mm off there
(15.8 mm); so the angles of every hidden part are mirrored, a seen hand keeping its own.

The hidden arm's clavicle is not mirrored but held: over the stretch it keeps its
angles at the stretch's known ends — the clicked frame, a frame where it was seen —
interpolated between two (:data:`HELD_PARTS`).  A frame counts as known where the
clavicle's own part was seen, not where only the hand was: on jumps_line3 the right
clavicle is never seen and keeps its clicked angles throughout.  Before, the hand's
points in frames 12–13 and 42–46 set it (elevation −2° and +12°) and the bridge
between them passed −6° at frame 20, against +6° at the clicked frame (the right
shoulder 40 mm off there), while on the truth the right shoulder moves at most 15 mm
about the neck over the take.  ``bench.fit_spread jumps_line3
--runs 4``: 15.24 / 15.90 / 15.43 / 15.76 → **13.51 / 15.20 / 14.07 / 14.93 mm**
(median 15.60 → 14.50); right shoulder 19 / 19 / 17 / 21 → 13 / 15 / 11 / 16, right
wrist 57 / 49 / 52 / 49 → 44 / 43 / 40 / 40 mm, right elbow within ±4 mm.  Mirrored
like the other angles instead, holding its offset from the mirror image at the
clicked frame: 14.43 / 15.70 / 15.82 / 15.31 (the right shoulder 15 mm off in frames
4–14 where held it was 6); mirrored with the offset faded out: runs 0 / 1 14.74 /
22.25 mm (run 1's clicks set the two clavicles apart: its right shoulder 50 mm off).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .fit_bridge import hidden_runs, unobserved
from .skeleton import Skeleton, forward, joint_positions

#: DOF-name prefixes (after ``l_``/``r_``) of the arms' parts that are mirrored; an arm
#: is hidden when its shoulder is
ARM_PARTS = ("clavicle", "shoulder", "elbow", "wrist")
#: the legs' angles whose mirror symmetry gates the mirroring (sagittal: they carry a
#: jump's or a squat's motion, and swing against each other in gait)
GATE_DOFS = ("hip_x", "knee_x")


@dataclass
class Mirroring:
    """One hidden stretch of one arm that :func:`mirror_hidden` considered.

    Attributes
    ----------
    limb : str, the hidden arm (``"r_arm"`` or ``"l_arm"``)
    frames : (a, b) half-open frame range
    r2 : float, how much of the legs' sagittal variance their mirror explains there
    mirrored : bool, whether the gate passed and the angles were replaced
    """

    limb: str
    frames: tuple[int, int]
    r2: float
    mirrored: bool


#: arm parts of a mirrored stretch that keep their own angles at the stretch's known
#: ends (interpolated between two) instead of taking the other side's: the clavicles,
#: seldom seen, which hardly move in the movements mirrored here
HELD_PARTS: tuple[str, ...] = ("clavicle",)


def _held_angles(value: np.ndarray, known: np.ndarray, c: int, d: int) -> np.ndarray:
    """``value`` (F,) over frames ``c:d`` from the known frames at either end: linear
    between two, constant from one, zero from none."""
    t = np.arange(c, d, dtype=float)
    ends = [(f, value[f]) for f in (c - 1, d) if 0 <= f < len(value) and known[f]]
    if not ends:
        return np.zeros(d - c)
    if len(ends) == 1:
        return np.full(d - c, ends[0][1])
    (fa, oa), (fb, ob) = ends
    return oa + (ob - oa) * (t - fa) / (fb - fa)


def _faded_offset(offset: np.ndarray, known: np.ndarray, c: int, d: int, blend: int) -> np.ndarray:
    """``offset`` (F,) at the known frames either side of ``c:d``, each fading out over
    ``blend`` frames into the stretch."""
    t = np.arange(c, d)
    y = np.zeros(d - c)
    if c > 0 and known[c - 1]:
        y += np.clip(1.0 - (t - (c - 1)) / blend, 0.0, 1.0) * offset[c - 1]
    if d < len(offset) and known[d]:
        y += np.clip(1.0 - (d - t) / blend, 0.0, 1.0) * offset[d]
    return y


def mirror_pairs(skel: Skeleton, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Left/right DOF pairs and the sign that mirrors one onto the other.

    Reflecting a rotation about axis ω by θ in the rest pose's mid-plane (normal to
    ``l_hip − r_hip``) gives a rotation about Mω by −θ.  The right DOF's axis is ±Mω of
    the left's at rest, so ``θ_r = sign · θ_l`` with ``sign = −(ω_r · Mω_l)``.

    Returns
    -------
    left, right : (m,) int DOF indices; sign : (m,) float, ±1
    """
    n = skel.n_dof
    axes = forward(skel, np.zeros(n), np.zeros(3), s).axes[0]
    joints = joint_positions(skel, np.zeros(n), np.zeros(3), s).reshape(-1, 3)
    lat = joints[skel.joint_index("l_hip")] - joints[skel.joint_index("r_hip")]
    lat /= np.linalg.norm(lat)
    M = np.eye(3) - 2.0 * np.outer(lat, lat)
    left, right = [], []
    for k, name in enumerate(skel.dof_names):
        if name.startswith("l_") and "r_" + name[2:] in skel.dof_names:
            left.append(k)
            right.append(skel.dof_index("r_" + name[2:]))
    left, right = np.array(left, int), np.array(right, int)
    sign = -np.sign(np.einsum("mi,ij,mj->m", axes[right], M, axes[left]))
    return left, right, sign


def legs_mirror_r2(
    skel: Skeleton, theta: np.ndarray, pairs, frames: np.ndarray, min_motion: float
) -> float:
    """Share of the right leg's sagittal variance that the mirrored left leg explains.

    Parameters
    ----------
    theta : (F, n) radians; pairs : :func:`mirror_pairs`' output
    frames : (T,) int frames to judge on
    min_motion : radians; legs whose pooled standard deviation is below it (standing)
        do not show a mirrored movement: −inf

    Returns
    -------
    r2 : float, ``1 − Σ(θ_r − sign·θ_l)² / Σ(θ_r − mean θ_r)²`` over the gate DOFs
    """
    left, right, sign = pairs
    rows = [i for i in range(len(left)) if skel.dof_names[left[i]][2:] in GATE_DOFS]
    a = theta[np.ix_(frames, left[rows])] * sign[rows]
    b = theta[np.ix_(frames, right[rows])]
    spread = ((b - b.mean(axis=0)) ** 2).sum()
    if len(frames) < 2 or np.sqrt(spread / b.size) < min_motion:
        return -np.inf
    return float(1.0 - ((a - b) ** 2).sum() / spread)


def mirror_hidden(
    skel: Skeleton,
    theta: np.ndarray,
    s: np.ndarray,
    hidden: np.ndarray,
    diverged: np.ndarray | None = None,
    anchors: tuple = (),
    r2_min: float = 0.8,
    min_motion: float = 0.05,
    margin: int = 5,
    blend: int = 5,
) -> tuple[np.ndarray, np.ndarray, list[Mirroring]]:
    """Replace a hidden arm's angles by the other arm's, mirrored (see the module text).

    Parameters
    ----------
    theta : (F, n) fitted angles, radians
    s : (G,) bone scales
    hidden : (F, n) bool, angles of parts without observations of their own (only
        these are replaced, and only from an arm angle that moves some part that is
        not hidden, :func:`core.fit_bridge.unobserved`)
    diverged : (F,) bool, frames that are only a prediction (neither replaced nor
        judged on)
    anchors : frames whose pose is known whether or not the parts were seen (the
        clicked frame): kept, their offset from the mirror image fading out
    r2_min : the legs' mirror symmetry needed over a stretch (see
        :func:`legs_mirror_r2`), judged on the stretch and ``margin`` frames each side
    min_motion : radians, the legs' least standard deviation over that window
    blend : frames over which an observed end's offset from the mirror image fades
        (:data:`HELD_PARTS` keep their own angles instead)

    Returns
    -------
    theta : (F, n) a copy with the mirrored stretches replaced
    mirrored : (F, n) bool, the angles replaced
    report : one :class:`Mirroring` per hidden stretch considered
    """
    theta = np.array(theta, float)
    hidden = np.asarray(hidden, bool)
    nf = len(theta)
    div = np.zeros(nf, bool) if diverged is None else np.asarray(diverged, bool)
    blend = max(int(blend), 1)
    fixed = np.zeros(nf, bool)
    fixed[[f for f in anchors if 0 <= f < nf]] = True
    pairs = mirror_pairs(skel, s)
    left, right, sign = pairs
    source = theta.copy()  # the observed arm before anything is replaced
    # a source angle serves wherever any part it moves was seen (an upper arm with few
    # points of its own is still placed by its forearm's)
    unseen = unobserved(hidden, skel.dof_parent)
    mirrored = np.zeros_like(hidden)
    report: list[Mirroring] = []
    arm = np.array([skel.dof_names[k][2:].rsplit("_", 1)[0] in ARM_PARTS for k in left])
    for side, (dst, src) in (("r", (right, left)), ("l", (left, right))):
        dst, src, sg = dst[arm], src[arm], sign[arm]
        key = np.array([skel.dof_names[j][2:].startswith("shoulder") for j in dst])
        stretch = hidden[:, dst[key]].all(axis=1) & ~unseen[:, src[key]].any(axis=1) & ~div & ~fixed
        for a, b in hidden_runs(stretch):
            win = np.arange(max(0, a - margin), min(nf, b + margin))
            r2 = legs_mirror_r2(skel, source, pairs, win[~div[win]], min_motion)
            ok_gate = r2 >= r2_min
            report.append(Mirroring(f"{side}_arm", (int(a), int(b)), r2, bool(ok_gate)))
            if not ok_gate:
                continue
            for j, k, g in zip(dst, src, sg, strict=True):
                gap = hidden[:, j] & ~unseen[:, k] & ~div & ~fixed
                gap[:a] = gap[b:] = False
                pred = g * source[:, k]
                known = (~hidden[:, j] | fixed) & ~div
                held = skel.dof_names[j][2:].rsplit("_", 1)[0] in HELD_PARTS
                for c, d in hidden_runs(gap):
                    if held:  # its own angles at the known ends, not the mirror's
                        y = _held_angles(theta[:, j], known, c, d)
                    else:
                        y = pred[c:d] + _faded_offset(theta[:, j] - pred, known, c, d, blend)
                    theta[c:d, j] = np.clip(y, skel.dof_lo[j], skel.dof_hi[j])
                    mirrored[c:d, j] = True
    return theta, mirrored, report
