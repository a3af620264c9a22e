"""Metrics of a fitted state against a scene's ground truth (``truth.npz``).

* **MPJPE** (mm): mean Euclidean joint error over :data:`core.landmarks.METRIC_JOINTS`
  and over the evaluated frames; also per joint and per frame.
* **Maximum joint error** as % of the body height (``truth.npz`` ``height_m``): per frame
  the largest error over the metric joints; reported as its maximum over frames and
  the share of frames within 1 %.
* **Segment orientation error** (degrees): the geodesic angle
  ``2·asin(‖R_t − R_f‖_F / (2√2))`` between the truth's and the fit's frame of each
  segment of :data:`core.landmarks.SEGMENTS`.  A segment frame is built from joints
  only, identically for truth and fit: first axis proximal → distal, second axis the
  component orthogonal to it of a reference direction between two neighbouring joints
  (:data:`SEGMENT_REFS`, e.g. the forearm for the upper arm, so that twist counts).
  Where, in the truth, the first reference is within 15° of the segment axis (a
  straight limb) the next reference is used, for truth and fit alike.  The head's
  twist is not observable from the joint set: its reference is the shoulder line.
  ``segment_orientation_rmse_deg`` is the RMSE over frames and the eight limb segments
  (upper/lower arms and legs); trunk and head are reported per segment.
* **Segment direction error** (degrees, ``segment_direction_rmse_deg``): the angle
  between the truth's and the fit's proximal → distal lines alone, RMSE over frames and
  the eight limb segments — the orientation without the twist about the segment's own
  axis.  Where a limb is straight the twist comes from the next segment (the forearm's
  from the hand), and the truth's ``hand`` joint is not the visible hand's direction
  (``docs/design.md``, "Fingers on the template hand"); this figure is free of that, and
  it is what a retarget that aims each bone at its child joint takes from the fit.
* **Acceleration error** (mm/frame², ``accel_error_mm``): the mean over the metric
  joints of ``‖Δ²x_fit − Δ²x_truth‖``, ``Δ²x = x(t+1) − 2 x(t) + x(t−1)``, over the
  frames whose two neighbours and itself are fitted (the jitter a viewer sees, as in the
  video pose literature; a fit that is off by a constant has none).
* **Diverged frames** (flag in the fitted state) are counted and left out of the
  error statistics; their per-frame curves hold NaN.
* **Metaball surface** (mm, ``surface_mm``, when the truth has the mesh: ``vertices``
  and ``faces``): the mean distance of the true mesh's surface, sampled by area, to the
  fitted ``Σ f = 0.5`` (:func:`surface_distance_mm`), on five fitted frames spread over
  the take.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import InputError
from .landmarks import METRIC_JOINTS, SEGMENTS
from .retarget import angle_between

#: Segment -> reference directions (from joint, to joint), tried in order.
SEGMENT_REFS = {
    "l_upper_arm": [("l_elbow", "l_wrist"), ("r_shoulder", "l_shoulder")],
    "l_forearm": [("l_elbow", "l_shoulder"), ("l_wrist", "l_hand"), ("r_shoulder", "l_shoulder")],
    "r_upper_arm": [("r_elbow", "r_wrist"), ("r_shoulder", "l_shoulder")],
    "r_forearm": [("r_elbow", "r_shoulder"), ("r_wrist", "r_hand"), ("r_shoulder", "l_shoulder")],
    "l_thigh": [("l_knee", "l_ankle"), ("r_hip", "l_hip")],
    "l_shin": [("l_ankle", "l_toe"), ("r_hip", "l_hip")],
    "r_thigh": [("r_knee", "r_ankle"), ("r_hip", "l_hip")],
    "r_shin": [("r_ankle", "r_toe"), ("r_hip", "l_hip")],
    "trunk": [("r_hip", "l_hip"), ("r_shoulder", "l_shoulder")],
    "head": [("r_shoulder", "l_shoulder"), ("r_hip", "l_hip")],
}

#: Segments whose RMSE forms ``segment_orientation_rmse_deg``.
LIMB_SEGMENTS = (
    "l_upper_arm",
    "l_forearm",
    "r_upper_arm",
    "r_forearm",
    "l_thigh",
    "l_shin",
    "r_thigh",
    "r_shin",
)

_MIN_REF_ANGLE = np.deg2rad(15.0)


@dataclass
class Evaluation:
    """Scores of one fit (F frames).  Lengths in mm, angles in degrees."""

    frames: int
    diverged_frames: int
    mpjpe_mm: float
    per_joint_mm: dict
    max_joint_error_pct_height: float
    frames_within_1pct: float
    segment_orientation_rmse_deg: float
    per_segment_rmse_deg: dict
    per_segment_max_deg: dict
    height_m: float
    segment_direction_rmse_deg: float = float("nan")  # the long axes alone (see above)
    per_segment_direction_rmse_deg: dict = field(default_factory=dict)
    curves: dict = field(repr=False, default_factory=dict)
    surface_mm: float = float("nan")  # the metaball surface to the true mesh (see above)
    accel_error_mm: float = float("nan")  # mm per frame², see the module text

    def to_json(self) -> dict:
        """The machine-readable summary (``--json``); per-frame curves excluded."""
        return {
            "mpjpe_mm": self.mpjpe_mm,
            "max_joint_error_pct_height": self.max_joint_error_pct_height,
            "frames_within_1pct_height": self.frames_within_1pct,
            "segment_orientation_rmse_deg": self.segment_orientation_rmse_deg,
            "segment_direction_rmse_deg": self.segment_direction_rmse_deg,
            "frames": self.frames,
            "diverged_frames": self.diverged_frames,
            "per_joint_mm": self.per_joint_mm,
            "per_segment_rmse_deg": self.per_segment_rmse_deg,
            "per_segment_max_deg": self.per_segment_max_deg,
            "per_segment_direction_rmse_deg": self.per_segment_direction_rmse_deg,
            "height_m": self.height_m,
            "surface_mm": self.surface_mm,
            "accel_error_mm": self.accel_error_mm,
        }


def segment_frames(xyz: np.ndarray, names: tuple | list, choice: dict | None = None):
    """Segment frames (F, 3, 3) per segment built from joint positions.

    Parameters
    ----------
    xyz : (F, J, 3) joint positions, metres
    names : the J joint names
    choice : segment -> (F,) int index into :data:`SEGMENT_REFS` (which reference to
        use per frame); chosen from ``xyz`` itself when omitted.

    Returns
    -------
    frames : dict segment -> (F, 3, 3), columns = (axis, second, third)
    choice : dict segment -> (F,) int
    """
    idx = {n: i for i, n in enumerate(names)}
    out, chosen = {}, {}
    for seg, (a, b) in SEGMENTS.items():
        e1 = xyz[:, idx[b]] - xyz[:, idx[a]]
        e1 = e1 / np.maximum(np.linalg.norm(e1, axis=-1, keepdims=True), 1e-12)
        refs = [r for r in SEGMENT_REFS[seg] if r[0] in idx and r[1] in idx]
        vs = np.stack([xyz[:, idx[q]] - xyz[:, idx[p]] for p, q in refs], axis=1)  # (F,K,3)
        if choice is None:
            vn = vs / np.maximum(np.linalg.norm(vs, axis=-1, keepdims=True), 1e-12)
            sin = np.linalg.norm(np.cross(vn, e1[:, None]), axis=-1)
            good = sin > np.sin(_MIN_REF_ANGLE)
            good[:, -1] = True
            c = np.argmax(good, axis=1)
        else:
            c = choice[seg]
        v = vs[np.arange(len(c)), c]
        e2 = v - e1 * np.sum(v * e1, axis=-1, keepdims=True)
        e2 = e2 / np.maximum(np.linalg.norm(e2, axis=-1, keepdims=True), 1e-12)
        out[seg] = np.stack([e1, e2, np.cross(e1, e2)], axis=-1)
        chosen[seg] = c
    return out, chosen


def geodesic_deg(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Angle (degrees) of ``Raᵀ Rb`` for stacks of rotations (..., 3, 3)."""
    d = np.linalg.norm(Ra - Rb, axis=(-2, -1)) / (2.0 * np.sqrt(2.0))
    return np.rad2deg(2.0 * np.arcsin(np.clip(d, 0.0, 1.0)))


def axis_angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Angle (degrees) between the first columns (the segments' long axes) of two stacks
    of segment frames (..., 3, 3): the orientation error without the twist."""
    return np.rad2deg(angle_between(Ra[..., :, 0], Rb[..., :, 0]))


def truth_joints(truth: dict, path: str | Path = "truth.npz") -> tuple[np.ndarray, list]:
    """``(joints_xyz (F, J, 3), names)`` from a truth dict, validated."""
    for key in ("joints_xyz", "joint_names", "height_m"):
        if key not in truth:
            raise InputError(f"{path}: is missing the array '{key}'")
    xyz = np.asarray(truth["joints_xyz"], dtype=float)
    names = [str(n) for n in truth["joint_names"]]
    if xyz.ndim != 3 or xyz.shape[1:] != (len(names), 3):
        raise InputError(
            f"{path}: joints_xyz has shape {list(xyz.shape)}, expected (F, {len(names)}, 3)"
        )
    missing = [j for j in METRIC_JOINTS if j not in names]
    if missing:
        raise InputError(f"{path}: joint_names lacks the metric joints {missing}")
    if not np.all(np.isfinite(xyz)):
        raise InputError(f"{path}: joints_xyz contains NaN or infinite values")
    return xyz, names


def evaluate(
    fit_xyz: np.ndarray,
    truth_xyz: np.ndarray,
    names: list,
    height_m: float,
    diverged: np.ndarray | None = None,
) -> Evaluation:
    """Score fitted joint positions against the truth.

    Parameters
    ----------
    fit_xyz, truth_xyz : (F, J, 3) world joint positions, metres, same joint order
    names : the J joint names (must include METRIC_JOINTS and the SEGMENTS joints)
    height_m : body height, metres
    diverged : (F,) bool, frames flagged diverged by the fit (left out of the stats)

    Returns
    -------
    Evaluation
    """
    fit_xyz = np.asarray(fit_xyz, float)
    truth_xyz = np.asarray(truth_xyz, float)
    nf = truth_xyz.shape[0]
    diverged = np.zeros(nf, bool) if diverged is None else np.asarray(diverged, bool)
    ok = ~diverged
    idx = {n: i for i, n in enumerate(names)}
    mj = [idx[j] for j in METRIC_JOINTS]
    err_mm = np.linalg.norm(fit_xyz[:, mj] - truth_xyz[:, mj], axis=-1) * 1000.0  # (F, K)
    err_mm[~ok] = np.nan
    per_frame_mpjpe = err_mm.mean(axis=1)
    per_frame_max_pct = err_mm.max(axis=1) / (height_m * 1000.0) * 100.0
    ft, choice = segment_frames(truth_xyz, names)
    ff, _ = segment_frames(fit_xyz, names, choice)
    seg_curves = {seg: np.where(ok, geodesic_deg(ft[seg], ff[seg]), np.nan) for seg in SEGMENTS}
    dir_curves = {seg: np.where(ok, axis_angle_deg(ft[seg], ff[seg]), np.nan) for seg in SEGMENTS}
    n_ok = int(ok.sum())
    d2 = (fit_xyz - truth_xyz)[:, mj]
    d2 = d2[2:] - 2.0 * d2[1:-1] + d2[:-2]  # Δ² of the fit minus Δ² of the truth
    ok3 = ok[2:] & ok[1:-1] & ok[:-2]
    accel = np.linalg.norm(d2[ok3], axis=-1) * 1000.0

    def _mean(a):
        return float(np.nanmean(a)) if n_ok else float("nan")

    def _rms(a):
        return float(np.sqrt(np.nanmean(np.square(a)))) if n_ok else float("nan")

    def _max(a):
        return float(np.nanmax(a)) if n_ok else float("nan")

    return Evaluation(
        frames=nf,
        diverged_frames=int(diverged.sum()),
        mpjpe_mm=_mean(err_mm),
        per_joint_mm={j: _mean(err_mm[:, k]) for k, j in enumerate(METRIC_JOINTS)},
        max_joint_error_pct_height=_max(per_frame_max_pct),
        frames_within_1pct=float(np.mean(per_frame_max_pct[ok] <= 1.0)) if n_ok else 0.0,
        segment_orientation_rmse_deg=_rms(np.stack([seg_curves[s] for s in LIMB_SEGMENTS])),
        per_segment_rmse_deg={s: _rms(c) for s, c in seg_curves.items()},
        per_segment_max_deg={s: _max(c) for s, c in seg_curves.items()},
        height_m=float(height_m),
        segment_direction_rmse_deg=_rms(np.stack([dir_curves[s] for s in LIMB_SEGMENTS])),
        per_segment_direction_rmse_deg={s: _rms(c) for s, c in dir_curves.items()},
        accel_error_mm=float(accel.mean()) if accel.size else float("nan"),
        curves={
            "mpjpe_mm": per_frame_mpjpe,
            "max_pct_height": per_frame_max_pct,
            "joint_mm": err_mm,
            **{f"seg_{s}": c for s, c in seg_curves.items()},
            **{f"dir_{s}": c for s, c in dir_curves.items()},
        },
    )


def evaluate_state(
    state, truth: dict, truth_path: str | Path = "truth.npz", fit_path: str | Path = "fit.json"
) -> Evaluation:
    """Score a :class:`core.state.FitState` against a scene's truth dict."""
    txyz, names = truth_joints(truth, truth_path)
    if state.n_frames != txyz.shape[0]:
        raise InputError(
            f"{fit_path}: has {state.n_frames} frames but {truth_path} has {txyz.shape[0]}"
        )
    missing = [n for n in names if n not in state.skeleton.joint_names]
    if missing:
        raise InputError(f"{fit_path}: the skeleton lacks the joints {missing}")
    fxyz = state.joints_xyz(names)
    ev = evaluate(fxyz, txyz, names, float(truth["height_m"]), state.quality.diverged)
    ok = np.flatnonzero(~np.asarray(state.quality.diverged, bool))
    if "vertices" in truth and "faces" in truth and len(ok):
        ev.surface_mm = surface_distance_mm(
            state, truth["vertices"], truth["faces"], ok[:: max(1, len(ok) // 5)].tolist()
        )
    return ev


def sample_mesh_surface(
    vertices: np.ndarray, faces: np.ndarray, n: int, rng: np.random.Generator
) -> np.ndarray:
    """Points (n, 3) drawn uniformly by area on a triangle mesh.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
        Mesh vertices, world metres.
    faces : ndarray, shape (T, 3)
        Triangles (vertex indices).
    n : int
        Number of points.
    rng : numpy.random.Generator
    """
    v = np.asarray(vertices, float)
    faces = np.asarray(faces, int)
    a, b, c = v[faces[:, 0]], v[faces[:, 1]], v[faces[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    k = rng.choice(len(faces), n, p=area / area.sum())
    u, w = rng.random(n), rng.random(n)
    flip = u + w > 1.0
    u[flip], w[flip] = 1.0 - u[flip], 1.0 - w[flip]
    return a[k] + u[:, None] * (b[k] - a[k]) + w[:, None] * (c[k] - a[k])


def surface_distance_mm(
    state,
    vertices: np.ndarray,
    faces: np.ndarray,
    frames: list[int],
    per_frame: int = 2000,
    seed: int = 0,
) -> float:
    """Mean distance (mm) of the true mesh's surface to the fitted metaball surface.

    The mesh surface is sampled uniformly by area (``per_frame`` points per frame on its
    triangles) and each sample projected onto the fitted ``Σ f = 0.5``
    (:func:`core.metaball_surface.project_to_surface`).  Sampling by area, not by vertex: the
    character's vertices crowd on the head, hands and feet (1,600 on each hand of
    13,380), so a vertex mean weighs those several times their area (make demo's walk:
    22.8 mm per vertex, 25.7 mm by area).

    Parameters
    ----------
    state : core.state.FitState
        The fitted state.
    vertices : ndarray, shape (F, V, 3)
        True mesh vertices per frame, world metres.
    faces : ndarray, shape (T, 3)
        The mesh's triangles (vertex indices).
    frames : list of int
        Frames to measure.
    """
    from . import metaball_surface as mbs
    from . import metaballs as mb
    from .skeleton import forward

    rng = np.random.default_rng(seed)
    out = []
    for f in frames:
        p = sample_mesh_surface(vertices[f], faces, per_frame, rng)
        pose = forward(state.skeleton, state.theta[f][None], state.root_xyz[f][None], state.s)
        Rw, cw = mb.world_frames(state.skeleton, pose, state.metaballs, state.s)
        xs, ok = mbs.project_to_surface(
            p, Rw[0], cw[0], state.metaballs.radii, iterations=60, tol=1e-6
        )
        out.append(np.linalg.norm(xs - p, axis=1)[ok])
    return float(np.mean(np.concatenate(out)) * 1000.0)


def plot(ev: Evaluation, path: str | Path, fps: float = 25.0, title: str = "") -> Path:
    """Write PNG error curves (MPJPE, max error % height, segment angles) per frame."""
    with warnings.catch_warnings():
        # matplotlib's pyparsing use emits DeprecationWarnings on newer pyparsing
        warnings.simplefilter("ignore", DeprecationWarning)
        return _plot(ev, Path(path), fps, title)


def _plot(ev: Evaluation, path: Path, fps: float, title: str) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.arange(ev.frames) / fps
    fig, axes = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
    axes[0].plot(t, ev.curves["mpjpe_mm"], label="MPJPE")
    axes[0].set_ylabel("mm")
    axes[0].legend(loc="upper right")
    axes[1].plot(t, ev.curves["max_pct_height"], color="C3", label="max joint error")
    axes[1].axhline(1.0, color="k", lw=0.5, ls="--")
    axes[1].set_ylabel("% of height")
    axes[1].legend(loc="upper right")
    for seg in SEGMENTS:
        axes[2].plot(t, ev.curves[f"seg_{seg}"], lw=0.8, label=seg)
    axes[2].set_ylabel("degrees")
    axes[2].set_xlabel("time (s)")
    axes[2].legend(loc="upper right", fontsize=6, ncol=2)
    fig.suptitle(title or "Errors against truth")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
