"""Limb coupling: a hidden limb's angles predicted from the opposite thigh's swing.

In gait the limbs move together: an arm swings with the opposite thigh, a leg against
it.  When a limb is unobserved for a stretch (every part it moves hidden in every
camera, :func:`core.fit_bridge.unobserved`), the frames where it *was* observed teach
that coupling, and the opposite thigh, still observed, tells where the limb went.

:func:`couple_hidden` fits, per limb and per angle, a straight line ``θ_j ≈ c0 + c1·d``
on the frames where the limb was observed, ``d`` being the driver
(:func:`segment_swing`: the opposite thigh's direction in the pelvis frame, reduced to
its first principal component).  An angle is coupled only when its line explains at
least ``r2_min`` (half) of its variance over the observed frames.  Each unobserved run
of a coupled angle gets the line's prediction, shifted to meet the fitted angle at both
ends (the two end residuals interpolated across) and clipped to the joint limits, when
the run has an observed frame on both sides and the coupling was seen on both sides of
it (``min_side`` training frames before and after: the prediction interpolates in time),
and only where the driver over the run stays within its range on the training frames,
widened by ``reach`` (a quarter) of it each side: the line interpolates in the driver
too.  An arm seen only while the opposite thigh is behind (make demo's right arm) gives
a line for that half of the swing; extrapolated to the forward half (1.7 times its range
beyond it) it put the upper arm 44–53° off in three of four click draws once its R²
passed the gate (``docs/design.md``, "A foot turned to its points, and a coupling not
extrapolated").  Runs at the start or end of the sequence are left alone unless ``ends``
is set (on the jumps clip that made a 3-frame end run worse; counting the clicked frame
as observed and coupling its arm from one frame before and 12 after a 34-frame run sent
the elbow 320 mm off).  What is not coupled (a jump, a dance step, an angle that does
not follow the thigh) is left to :func:`core.fit_mirror.mirror_hidden` (an arm, where
the legs move mirrored) and then to :func:`core.fit_bridge.bridge_hidden`.  A t test on
the slope instead of the R² let an arm swinging at an unrelated frequency through:
neighbouring frames of a smooth motion are not independent samples.

On make demo's walk the right arm is behind the trunk in all three cameras in frames
8–24 and 36–49, swinging back where no camera sees it.  On the truth, the opposite
thigh's swing predicts that arm's swing angle within 2–12° where the interpolating
bridge is 26° off at mid-gap.  On the demo's fit (in-process, one BLAS thread): MPJPE
15.17 → 12.23 mm, right wrist at mid-gap 223 → 54 mm; jumps_line3 unchanged (20.48).
The gain is fragile: the arm was seen only in the forward half of its swing, where
the thigh is near its extreme, and two shoulder angles pass the gate with R² 0.54 and
0.62 (at ``r2_min`` 0.6 only one does and MPJPE is 14.98 mm).  The swing of the upper
arm as a whole correlates with the thigh's over those frames at R² 0.10 only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .fit_bridge import bridge_hidden, fill_runs, hidden_runs
from .fit_gait import gait_swing_arms
from .fit_mirror import mirror_hidden
from .fit_reattach import reattach_seen
from .fit_smooth import smooth_held
from .skeleton import Skeleton, bone_frames, forward, joint_positions

#: a limb's DOF-name prefixes (after ``l_``/``r_``)
LIMB_PARTS = {
    "arm": ("clavicle", "shoulder", "elbow", "wrist"),
    "leg": ("hip", "knee", "ankle"),
    "thigh": ("hip",),
}


@dataclass
class Coupling:
    """What :func:`couple_hidden` did for one limb.

    Attributes
    ----------
    limb : str, e.g. ``"r_arm"``
    r2 : float, coefficient of determination on the limb's observed frames, pooled
        over its coupled angles (0 when none is)
    n_train : int, frames the lines were fitted on
    frames : int, frames with angles replaced
    beyond : int, unobserved runs left alone because the driver there reaches beyond
        the range it spanned on the training frames (``reach``)
    """

    limb: str
    r2: float
    n_train: int
    frames: int
    beyond: int = 0


def limb_dofs(skel: Skeleton, side: str, limb: str) -> np.ndarray:
    """Indices of the DOFs of one limb, e.g. ``limb_dofs(skel, "r", "arm")``."""
    parts = LIMB_PARTS[limb]
    return np.array(
        [
            k
            for k, n in enumerate(skel.dof_names)
            if n.startswith(side + "_") and n[2:].rsplit("_", 1)[0] in parts
        ],
        int,
    )


def segment_swing(
    skel: Skeleton,
    theta: np.ndarray,
    root_xyz: np.ndarray,
    s: np.ndarray,
    head: str,
    tail: str,
    use: np.ndarray,
) -> np.ndarray:
    """The swing of one body segment: (F,) first principal component of its direction.

    Parameters
    ----------
    theta : (F, n) radians; root_xyz : (F, 3) metres; s : (G,) bone scales
    head, tail : joint names, e.g. ``"l_hip"``, ``"l_knee"`` for the left thigh
    use : (F,) bool, the frames the principal axis is taken from

    Returns
    -------
    (F,) unit-less score (about radians for small swings): the head→tail unit vector in
    the pelvis bone frame, centred on its mean over ``use`` and projected on the axis of
    its largest variance there.
    """
    x = joint_positions(skel, theta, root_xyz, s)
    u = x[:, skel.joint_names.index(tail)] - x[:, skel.joint_names.index(head)]
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    Rb, _ = bone_frames(skel, forward(skel, theta, root_xyz, s))
    local = np.einsum("fji,fj->fi", Rb[:, skel.bone_index("pelvis")], u)
    mean = local[use].mean(axis=0)
    _, _, vt = np.linalg.svd(local[use] - mean, full_matrices=False)
    return (local - mean) @ vt[0]


def coupling_lines(
    d: np.ndarray, y: np.ndarray, r2_min: float
) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares lines ``y ≈ c0 + c1·d`` and which of them the data bear out.

    Parameters
    ----------
    d : (T,) driver on the training frames; y : (T, m) angles there, radians
    r2_min : the share of a column's variance its line must explain

    Returns
    -------
    coef : (2, m) intercepts and slopes; keep : (m,) bool; r2 : float, pooled over
    the kept columns (0 when none is)
    """
    nt = len(d)
    A = np.column_stack([np.ones(nt), d])
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    ss_res = ((y - A @ coef) ** 2).sum(axis=0)
    ss_tot = ((y - y.mean(axis=0)) ** 2).sum(axis=0)
    r2 = np.where(ss_tot > 1e-12, 1.0 - ss_res / np.maximum(ss_tot, 1e-12), 0.0)
    keep = r2 >= r2_min
    pooled = float(1.0 - ss_res[keep].sum() / ss_tot[keep].sum()) if keep.any() else 0.0
    return coef, keep, pooled


def couple_hidden(
    skel: Skeleton,
    theta: np.ndarray,
    root_xyz: np.ndarray,
    s: np.ndarray,
    unobserved: np.ndarray,
    diverged: np.ndarray | None = None,
    r2_min: float = 0.5,
    min_train: int = 8,
    min_side: int = 4,
    ends: bool = False,
    reach: float | None = 0.25,
) -> tuple[np.ndarray, np.ndarray, list[Coupling]]:
    """Predict unobserved limb angles from the opposite thigh (see the module text).

    Parameters
    ----------
    theta : (F, n) fitted angles, radians
    root_xyz : (F, 3) metres; s : (G,) bone scales
    unobserved : (F, n) bool, angles whose parts were hidden in every camera
    diverged : (F,) bool, frames that are only a prediction (never train or anchor)
    r2_min : the share of an angle's variance over the observed frames its line must
        explain
    min_train : fewest observed frames to fit on
    min_side : fewest of them on each side of a run (else the run is left)
    ends : also couple runs at the start or end of the sequence (one observed end:
        its residual is held)
    reach : a run is coupled only where the driver stays within the range it spans on
        the training frames, widened by this share of that range on each side (None:
        no limit).  A line fitted to one half of a swing does not tell the other half.

    Returns
    -------
    theta : (F, n) a copy with the coupled runs replaced
    coupled : (F, n) bool, the angles replaced
    report : one :class:`Coupling` per limb that had unobserved angles
    """
    theta = np.array(theta, float)
    unobs = np.asarray(unobserved, bool)
    nf = len(theta)
    div = np.zeros(nf, bool) if diverged is None else np.asarray(diverged, bool)
    coupled = np.zeros_like(unobs)
    report: list[Coupling] = []
    for side, other in (("l", "r"), ("r", "l")):
        # the driver needs only the thigh observed (a hidden foot does not move it)
        drv_ok = ~unobs[:, limb_dofs(skel, other, "thigh")].any(axis=1) & ~div
        d = None
        for limb in ("arm", "leg"):
            dofs = limb_dofs(skel, side, limb)
            dofs = dofs[unobs[:, dofs].any(axis=0)]
            if not len(dofs):
                continue
            train = ~unobs[:, dofs].any(axis=1) & drv_ok
            name, n_t = f"{side}_{limb}", int(train.sum())
            if n_t < min_train:
                report.append(Coupling(name, 0.0, n_t, 0))
                continue
            if d is None:
                d = segment_swing(skel, theta, root_xyz, s, other + "_hip", other + "_knee", drv_ok)
            coef, keep, r2 = coupling_lines(d[train], theta[train][:, dofs], r2_min)
            replaced = np.zeros(nf, bool)
            lo, hi = d[train].min(), d[train].max()
            margin = np.inf if reach is None else reach * (hi - lo)
            beyond = set()
            # a run needs the coupling seen on both sides of it (time interpolation, not
            # extrapolation): at least min_side training frames before and after
            before = np.cumsum(train)
            for j, c0, c1 in zip(dofs[keep], *coef[:, keep], strict=True):
                y = theta[:, j].copy()
                ok = ~unobs[:, j] & ~div
                gap = ~ok & ~div & drv_ok  # a frame without the driver ends a run
                for a, b in hidden_runs(gap):
                    n_before = before[a - 1] if a > 0 else 0
                    if min(n_before, n_t - before[b - 1]) < min_side and not ends:
                        gap[a:b] = False
                    elif ((d[a:b] < lo - margin) | (d[a:b] > hi + margin)).any():
                        gap[a:b] = False  # the line would be extrapolated
                        beyond.add((a, b))
                done = fill_runs(y, c0 + c1 * d, gap, ok, ends)
                theta[done, j] = np.clip(y[done], skel.dof_lo[j], skel.dof_hi[j])
                coupled[done, j] = True
                replaced |= done
            report.append(Coupling(name, r2, n_t, int(replaced.sum()), len(beyond)))
    return theta, coupled, report


def fill_unobserved(
    skel: Skeleton,
    theta: np.ndarray,
    root_xyz: np.ndarray,
    s: np.ndarray,
    unobserved: np.ndarray,
    diverged: np.ndarray,
    couple: bool = True,
    bridge: bool = True,
    r2_min: float = 0.5,
    hidden: np.ndarray | None = None,
    anchors: tuple = (),
    mirror: bool = True,
    mirror_r2: float = 0.8,
    keep_seen: bool = True,
    smooth_width: int = 7,
    gait: bool = True,
    gait_ratio: float = 0.7,
    reach: float | None = 0.25,
) -> tuple[np.ndarray, list[str]]:
    """The sequence fit's last step: unobserved angles coupled, hidden arms mirrored, the
    rest bridged, what is left smoothed over time; in a walk, hidden arms swung with the
    opposite thigh.

    Parameters
    ----------
    theta : (F, n) fitted angles, radians (the unobserved ones held)
    root_xyz, s, unobserved, diverged : as :func:`couple_hidden`
    couple, bridge : run :func:`couple_hidden`, :func:`core.fit_bridge.bridge_hidden`
    r2_min, reach : :func:`couple_hidden`'s gates
    hidden : (F, n) bool, angles of parts without observations of their own (defaults
        to ``unobserved``)
    anchors : frames whose pose is known however little was seen (the clicked frame)
    mirror, mirror_r2 : run :func:`core.fit_mirror.mirror_hidden` with this gate on
        what the coupling left
    keep_seen : after mirroring, re-pose the seen parts below a mirrored one so they
        stay where their points put them (:func:`core.fit_reattach.reattach_seen`)
    smooth_width : frames of the running median over the unobserved angles that none of
        these replaced (:func:`core.fit_smooth.smooth_held`; 1: none)
    gait, gait_ratio : last, in a walk, swing the hidden arms that neither the coupling
        nor the mirror placed with the opposite thigh, ``gait_ratio`` degrees per
        degree (:func:`core.fit_gait.gait_swing_arms`; their bridged or held shoulder
        angles are replaced)

    Returns
    -------
    theta : (F, n) a copy; messages : what was done, for the fit's report
    """
    theta = np.array(theta, float)
    unobs = np.asarray(unobserved, bool)
    hid = unobs if hidden is None else np.asarray(hidden, bool)
    left, msgs = unobs, []
    if couple:
        theta, coupled, report = couple_hidden(
            skel, theta, root_xyz, s, unobs, diverged, r2_min=r2_min, reach=reach
        )
        left = unobs & ~coupled
        hid = hid & ~coupled
        msgs += [
            f"{c.limb}: {c.frames} unobserved frames predicted from the opposite thigh "
            f"(R² {c.r2:.2f} on {c.n_train} observed frames)"
            for c in report
            if c.frames
        ]
        msgs += [
            f"{c.limb}: {c.beyond} unobserved stretches not predicted from the opposite "
            "thigh: it swings there beyond what the observed frames cover"
            for c in report
            if c.beyond
        ]
    if mirror:
        held = theta
        theta, mirrored, mreport = mirror_hidden(
            skel, theta, s, hid, diverged, anchors, r2_min=mirror_r2
        )
        left = left & ~mirrored
        msgs += [
            f"{m.limb}: hidden in frames {m.frames[0]}–{m.frames[1] - 1}, mirrored from "
            f"the other arm (the legs move mirrored there, R² {m.r2:.2f})"
            for m in mreport
            if m.mirrored
        ]
        if keep_seen and mirrored.any():
            theta, moved = reattach_seen(skel, held, theta, root_xyz, s, mirrored, hid, diverged)
            if moved.any():
                msgs.append(
                    f"{int(moved.any(axis=1).sum())} frames: the seen parts below a "
                    "mirrored one re-posed onto the places their points gave them"
                )
    swingable = left
    if bridge:
        theta, bridged = bridge_hidden(theta, left, diverged)
        left = left & ~bridged
        if bridged.any():
            msgs.append(
                f"{int(bridged.any(axis=1).sum())} frames with angles interpolated "
                "across an unobserved stretch"
            )
    theta, smoothed = smooth_held(theta, left, diverged, smooth_width)
    if smoothed.any():
        msgs.append(
            f"{int(smoothed.any(axis=1).sum())} frames with held angles smoothed over "
            f"{smooth_width} frames"
        )
    if gait:
        theta, _, greport = gait_swing_arms(
            skel, theta, root_xyz, s, unobs, swingable, diverged, ratio=gait_ratio
        )
        msgs += [
            f"{g.limb}: {g.frames} hidden frames swung with the opposite thigh "
            f"({gait_ratio:g} per degree; the thighs' swings correlate at {g.legs_r:.2f}, "
            f"the other arm swings {g.other_ratio:.2f} per degree)"
            for g in greport
            if g.frames
        ]
    return theta, msgs
