"""The feet's turn at the clicked frame, from the surface measured round each foot.

The clicks fix a foot's ankle but not its turn about the shin (``*_ankle_z``), unless
the toes are clicked too (:data:`core.landmarks.OPTIONAL_CLICK_JOINTS`), so the
initialisation leaves it at the template's.  The sequence fit then anchors that DOF
to the clicked posture, and the shape solve moves the foot's metaballs onto the
points rather than turning the foot: make demo's right foot stayed 17° turned out
through the take (limb segment ``r_shin`` 17°, ``docs/design.md``, "The feet's turn").

The points round a foot say where it points.  Seen from above, a shoe is long and
narrow: the major axis of its points' horizontal spread is the foot's heading to a
few degrees, while the template's round foot sections are indifferent to it.  For
each foot whose toe is not clicked:

* the points below the clicked ankle (by ``below_m``), near the foot's heel–toe line
  seen from above and nearer to it than to the other foot's, are the foot's (the
  line follows the heading found, and the split is made again);
* with at least ``min_points`` of them, spread at least ``min_elongation`` times
  longer than wide, their major axis — oriented to the side of the current toe — is
  the heading, and ``*_ankle_z`` is solved so that the ankle → toe line points
  there, within the joint's limits.

On the studio scenes' clicked frames (tracked points, ``--cues both``) the heading so
found is 1° and 3° from the truth's on make demo's walk (the template's: 2° and 18°
off), 1° on jumps_line3's seen foot (2°), 6° on pirouette_line3's right foot (26°) and
38° on dance_line3's left foot (79°: its split starts from a heel–toe line that far
off); the feet with too few points below the ankle (pirouette's left: 29; the jumps'
and the dance's right: none or 1) keep the template's.

It is off by default (``SequenceSettings.foot_heading``, ``core fit
--feet-from-points``).  Over the four click sets of ``bench.fit_spread --runs 4
--setting foot_heading=true`` on make demo's walk the right shin comes right (17.0 /
35.9 / 9.8 / 12.6 → 2.7 / 4.9 / 3.9 / 4.9°), but the left, whose heading the template
already had within 2°, does not stay where it is turned: from frame 1 the fit holds it
5–7° further out than the clicked frame set it (left shin 2.0 / 9.7 / 13.3 / 11.9 → 8.3
/ 5.2 / 10.7 / 10.9°), and MPJPE goes 9.7 / 12.3 / 13.1 / 13.7 → 10.3 / 13.8 / 13.5 /
13.5 mm (``docs/design.md``, "A foot turned to its points, and a coupling not
extrapolated").  World frame: Z up, metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .skeleton import Skeleton, joint_positions
from .skeleton_template import LIMITS


@dataclass(frozen=True)
class FootHeadingSettings:
    """Which points count as a foot's and when their spread gives its heading.

    Attributes
    ----------
    heel_m, toe_m : float
        A foot's heel–toe line runs from ``heel_m`` behind its ankle to ``toe_m``
        ahead of it, metres.
    lateral_m : float
        Largest horizontal distance of a foot's point from that line, metres.
    below_m : float
        A foot's points lie at least this far below the ankle, metres (the shin's do
        not).
    min_points : int
        Fewest points that give a heading.
    min_elongation : float
        Smallest ratio of the spread's major to minor standard deviation.
    rounds : int
        Splits of the points between the feet, each along the headings found before.
    """

    heel_m: float = 0.06
    toe_m: float = 0.2
    lateral_m: float = 0.08
    below_m: float = 0.02
    min_points: int = 40
    min_elongation: float = 1.5
    rounds: int = 3


@dataclass(frozen=True)
class FootHeading:
    """What was found for one foot.

    Attributes
    ----------
    side : "l" or "r"
    n_points : points taken as the foot's
    elongation : major / minor standard deviation of their horizontal spread
    heading_deg : the major axis's heading (atan2 of y, x), degrees, or None when the
        foot kept the template's turn
    before_deg, after_deg : the ankle → toe heading before and after, degrees
    clamped : the joint's limit stopped the turn short of the heading
    """

    side: str
    n_points: int
    elongation: float
    heading_deg: float | None
    before_deg: float
    after_deg: float
    clamped: bool = False

    def message(self) -> str:
        if self.heading_deg is None:
            return (
                f"{self.side}_ankle_z: kept ({self.n_points} points below the ankle, "
                f"spread {self.elongation:.1f}:1)"
            )
        limit = ", at the joint's limit" if self.clamped else ""
        return (
            f"{self.side}_ankle_z: the foot turned {self.before_deg:.0f}° -> "
            f"{self.after_deg:.0f}° (its {self.n_points} points point {self.heading_deg:.0f}°"
            f"{limit})"
        )


def _wrap(a: np.ndarray | float) -> np.ndarray | float:
    """Angle wrapped to (−π, π]."""
    return -((np.pi - np.asarray(a)) % (2 * np.pi) - np.pi)


def _toe_heading(skel: Skeleton, theta, root, s, ankle: int, toe: int) -> float:
    x = joint_positions(skel, theta, root, s)
    d = x[toe] - x[ankle]
    return float(np.arctan2(d[1], d[0]))


def _turn_to(skel, theta, root, s, joints, target: float, limits) -> np.ndarray:
    """``theta`` with DOF ``k`` turned (within ``limits``, radians) so that the
    ``ankle`` → ``toe`` line heads to ``target``: Newton on the wrapped heading error."""
    ankle, toe, k = joints
    t = np.array(theta, float)
    for _ in range(20):
        h0 = _toe_heading(skel, t, root, s, ankle, toe)
        err = float(_wrap(target - h0))
        if abs(err) < 1e-4:
            break
        t2 = t.copy()
        t2[k] += 1e-4
        slope = float(_wrap(_toe_heading(skel, t2, root, s, ankle, toe) - h0)) / 1e-4
        if abs(slope) < 0.2:  # the shin lies nearly flat: the turn hardly moves the toe
            break
        t[k] = np.clip(t[k] + np.clip(err / slope, -0.5, 0.5), *limits)
    return t


def _segment_distance(xy: np.ndarray, ankle: np.ndarray, u: np.ndarray, cfg) -> np.ndarray:
    """Horizontal distance (N,) of points ``xy`` (N, 2) to a foot's heel–toe line: from
    ``heel_m`` behind the ankle to ``toe_m`` ahead of it along the heading ``u`` (2,)."""
    t = np.clip((xy - ankle[:2]) @ u, -cfg.heel_m, cfg.toe_m)
    return np.linalg.norm(xy - ankle[:2] - t[:, None] * u, axis=1)


def foot_axes(xyz: np.ndarray, ankles: np.ndarray, headings: np.ndarray, cfg) -> list[tuple]:
    """The two feet's points and the major axes of their horizontal spread.

    A point belongs to the foot whose heel–toe line (from the ankle along its current
    heading) is nearer, within ``lateral_m``, and lies ``below_m`` under that ankle;
    the headings are re-estimated from the points and the split made again
    (``rounds`` times), so that two feet side by side share their points right.

    Parameters
    ----------
    xyz : (N, 3) world points, metres
    ankles : (2, 3) the feet's ankles, world metres
    headings : (2, 2) unit horizontal ankle → toe directions to start from
    cfg : FootHeadingSettings

    Returns
    -------
    list of two ``(n, elongation, axis)``: the points taken, the major / minor standard
    deviation of their horizontal spread (0 with fewer than 2), and the unit major
    axis (2,) pointing to the side of the heading (None with fewer than 2 points, or
    fewer than ``min_points``: such a foot keeps its heading)
    """
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    u = np.array(headings, float)
    out = [(0, 0.0, None), (0, 0.0, None)]
    for _ in range(cfg.rounds):
        d = np.stack([_segment_distance(xyz[:, :2], ankles[k], u[k], cfg) for k in (0, 1)])
        near = np.argmin(d, axis=0)
        for k in (0, 1):
            sel = (near == k) & (d[k] < cfg.lateral_m) & (xyz[:, 2] < ankles[k, 2] - cfg.below_m)
            n = int(sel.sum())
            if n < 2:
                out[k] = (n, 0.0, None)
                continue
            q = xyz[sel, :2] - xyz[sel, :2].mean(axis=0)
            w, v = np.linalg.eigh(q.T @ q / n)
            axis = v[:, 1] if v[:, 1] @ u[k] >= 0 else -v[:, 1]
            out[k] = (n, float(np.sqrt(w[1] / max(w[0], 1e-12))), axis)
            if n >= cfg.min_points and out[k][1] >= cfg.min_elongation:
                u[k] = axis
    return out


def feet_from_points(
    skel: Skeleton,
    theta: np.ndarray,
    root_xyz: np.ndarray,
    s: np.ndarray,
    xyz: np.ndarray,
    clicked: tuple | list = (),
    settings: FootHeadingSettings | None = None,
) -> tuple[np.ndarray, list[FootHeading]]:
    """Turn each foot about its shin to the heading of its points.

    Parameters
    ----------
    skel : Skeleton
    theta : (D,) joint angles of the clicked frame, radians
    root_xyz : (3,) root position, metres
    s : (G,) bone scales
    xyz : (N, 3) the clicked frame's surface points, world metres (Z up)
    clicked : names of the clicked joints (a foot whose toe is clicked is left alone)
    settings : FootHeadingSettings

    Returns
    -------
    theta : (D,) the angles with ``l_ankle_z`` / ``r_ankle_z`` turned (a copy)
    found : one :class:`FootHeading` per foot looked at
    """
    cfg = settings or FootHeadingSettings()
    theta = np.array(theta, float)
    x = joint_positions(skel, theta, root_xyz, s)
    ankle = [skel.joint_index(f"{k}_ankle") for k in "lr"]
    toe = [skel.joint_index(f"{k}_toe") for k in "lr"]
    u = np.array([x[t, :2] - x[a, :2] for a, t in zip(ankle, toe, strict=True)])
    u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-12)
    axes = foot_axes(xyz, x[ankle], u, cfg)
    found = []
    for i, side in enumerate("lr"):
        if f"{side}_toe" in clicked:
            continue
        dof = f"{side}_ankle_z"
        k = skel.dof_index(dof)
        before = _toe_heading(skel, theta, root_xyz, s, ankle[i], toe[i])
        n, elong, axis = axes[i]
        if axis is None or n < cfg.min_points or elong < cfg.min_elongation:
            deg = float(np.degrees(before))
            found.append(FootHeading(side, n, elong, None, deg, deg))
            continue
        target = float(np.arctan2(axis[1], axis[0]))
        lo, hi = np.radians(LIMITS[dof])
        t = _turn_to(skel, theta, root_xyz, s, (ankle[i], toe[i], k), target, (lo, hi))
        after = _toe_heading(skel, t, root_xyz, s, ankle[i], toe[i])
        if abs(_wrap(target - after)) < abs(_wrap(target - before)):
            theta = t
        else:
            t, after = theta, before
        found.append(
            FootHeading(
                side,
                n,
                elong,
                float(np.degrees(target)),
                float(np.degrees(before)),
                float(np.degrees(after)),
                bool(np.isclose(t[k], lo) or np.isclose(t[k], hi)),
            )
        )
    return theta, found
