"""The fitted-state file ``fit.json``: skeleton, shape, per-frame motion and quality.

Written by ``core fit`` (and :mod:`core.truth_state`), read by ``core evaluate`` and
by the Blender add-on.  One JSON object, UTF-8::

    {
      "format": "somacap.state",          # fixed
      "version": 1,                       # readers refuse a newer version
      "source_scene": "sample_scenes/walk_line3",   # informational
      "fps": 25.0,                        # frames per second of the take
      "frames": F,                        # frame count
      "skeleton": {                       # see core.skeleton (Skeleton.to_dict)
        "scale_groups": [G names],
        "dofs":  [{"name", "parent" (DOF index or -1 = root frame),
                   "d_ini_rot" 3x3, "d_ini_offset" [3] (metres, parent DOF frame,
                   before scaling), "scale_group" (index or -1),
                   "limits" [lo, hi] (radians, null = none)}, ...],   # n DOFs
        "bones": [{"name", "parent" (bone index or -1), "dof" (last DOF of its chain),
                   "post_rot" 3x3 (last DOF frame -> anatomical frame),
                   "head", "tail" (joint names)}, ...],               # B bones
        "joints": [{"name" (core.landmarks.JOINTS), "bone", "offset" [3] (metres,
                    bone's anatomical frame, before scaling), "scale_group"}, ...]
      },
      "scales": [G floats],               # s, per-subject scale coefficients
      "metaballs": {"model": "simplified" | "complete" | "...",
                    "items": [{"bone" (name), "center" [3] (bone frame, metres before
                               scaling), "scale_group", "rotation" 3x3 (axes in the bone
                               frame), "radii" [lx, ly, lz] (metres), optional
                               "visible_scale" [3] (rendered semi-axes / radii;
                               absent: sqrt(ln 2 / 2), a lone metaball's)}, ...]},
      "motion": {"dof_names": [n names],
                 "root_xyz": F x [3]  (metres, world, Z up),
                 "theta": F x [n]     (radians)},
      "quality": {"rmse_m": [F] (residual RMSE, metres, null = unknown),
                  "theta_sigma": F x [n] (σ of each angle, radians, null = unknown),
                  "converged": [F] bool, "diverged": [F] bool,
                  "cameras": F x {part: [camera names]},
                  "unobserved": optional F x [n] bool — angles no observation reached
                  that frame (every part they move hidden): held, or interpolated
                  across the gap (core.fit_bridge)},
      "joints_override": optional F x J x [3] — world joint positions that replace the
                 skeleton's (only for truth that the skeleton cannot reproduce)
    }

Kinematics (``core.skeleton``): ``F_k = F_parent · [d_ini_rot | s·d_ini_offset] ·
Rz(θ_k)``, root parent = translation by ``root_xyz``.  Bone world matrices for an
armature: :func:`bone_world_matrices` (Y along the bone, head at the origin).
A diverged frame still holds finite numbers (the prediction); consumers should skip
it or hold the previous pose.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import InputError
from .landmarks import JOINTS
from .metaballs import Metaballs
from .skeleton import Skeleton, bone_matrices, joint_positions

FORMAT = "somacap.state"
VERSION = 1


@dataclass
class Quality:
    """Per-frame quality of a fit (F frames, n DOFs)."""

    rmse_m: np.ndarray  # (F,) NaN = unknown
    theta_sigma: np.ndarray  # (F, n) NaN = unknown
    converged: np.ndarray  # (F,) bool
    diverged: np.ndarray  # (F,) bool
    cameras: list = field(default_factory=list)  # F dicts part -> [camera names]
    unobserved: np.ndarray | None = None  # (F, n) bool: angles no observation reached

    @classmethod
    def empty(cls, n_frames: int, n_dof: int, converged: bool = True) -> Quality:
        return cls(
            rmse_m=np.full(n_frames, np.nan),
            theta_sigma=np.full((n_frames, n_dof), np.nan),
            converged=np.full(n_frames, converged),
            diverged=np.zeros(n_frames, bool),
            cameras=[{} for _ in range(n_frames)],
        )


@dataclass
class FitState:
    """A fitted state in memory (see the module docstring for the file).

    Attributes
    ----------
    skeleton : Skeleton
    s : (G,) scale coefficients
    metaballs : Metaballs
    root_xyz : (F, 3) metres
    theta : (F, n) radians
    quality : Quality
    fps : float
    source_scene : str
    metaball_model : str
    joints_override : (F, J, 3) or None
    """

    skeleton: Skeleton
    s: np.ndarray
    metaballs: Metaballs
    root_xyz: np.ndarray
    theta: np.ndarray
    quality: Quality
    fps: float = 25.0
    source_scene: str = ""
    metaball_model: str = "simplified"
    joints_override: np.ndarray | None = None

    @property
    def n_frames(self) -> int:
        return int(self.theta.shape[0])

    def joints_xyz(self, names: tuple | list = JOINTS) -> np.ndarray:
        """Per-frame joint world positions (F, len(names), 3), metres."""
        if self.joints_override is not None:
            allj = self.joints_override
        else:
            allj = joint_positions(self.skeleton, self.theta, self.root_xyz, self.s)
        idx = [self.skeleton.joint_index(n) for n in names]
        return allj[:, idx]

    def bone_matrices(self) -> np.ndarray:
        """Per-frame bone world matrices (F, B, 4, 4); names ``skeleton.bone_names``."""
        return bone_matrices(self.skeleton, self.theta, self.root_xyz, self.s)


def bone_world_matrices(state: FitState) -> tuple[tuple, np.ndarray]:
    """``(bone_names, matrices (F, B, 4, 4))`` for building an armature.

    Each matrix maps bone-local to world (Z up, metres); origin at the bone's head
    joint, Y axis from head to tail in the rest pose, X towards the subject's left.
    Bone parents: ``state.skeleton.bone_parent``.
    """
    return state.skeleton.bone_names, state.bone_matrices()


# -- writing ----------------------------------------------------------------------------
def _nan_to_none(a: np.ndarray):
    a = np.asarray(a, dtype=float)
    return (
        [None if not math.isfinite(v) else float(v) for v in a.ravel()]
        if a.ndim == 1
        else [_nan_to_none(row) for row in a]
    )


def state_to_dict(state: FitState) -> dict:
    """The JSON object of a state (see the module docstring)."""
    q = state.quality
    out = {
        "format": FORMAT,
        "version": VERSION,
        "source_scene": str(state.source_scene),
        "fps": float(state.fps),
        "frames": state.n_frames,
        "skeleton": state.skeleton.to_dict(),
        "scales": [float(v) for v in state.s],
        "metaballs": {
            "model": state.metaball_model,
            "items": state.metaballs.to_dict(state.skeleton),
        },
        "motion": {
            "dof_names": list(state.skeleton.dof_names),
            "root_xyz": np.asarray(state.root_xyz, float).tolist(),
            "theta": np.asarray(state.theta, float).tolist(),
        },
        "quality": {
            "rmse_m": _nan_to_none(q.rmse_m),
            "theta_sigma": _nan_to_none(q.theta_sigma),
            "converged": [bool(v) for v in q.converged],
            "diverged": [bool(v) for v in q.diverged],
            "cameras": [dict(c) for c in q.cameras],
        },
    }
    if q.unobserved is not None:
        out["quality"]["unobserved"] = np.asarray(q.unobserved, bool).tolist()
    if state.joints_override is not None:
        out["joints_override"] = np.asarray(state.joints_override, float).tolist()
    return out


def write_state(path: str | Path, state: FitState) -> Path:
    """Write ``fit.json``; refuses non-finite motion (raises ValueError: a bug upstream)."""
    for name, arr in (("theta", state.theta), ("root_xyz", state.root_xyz), ("s", state.s)):
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"refusing to write a state with non-finite {name}")
    path = Path(path)
    path.write_text(json.dumps(state_to_dict(state), allow_nan=False), encoding="utf-8")
    return path


# -- reading ----------------------------------------------------------------------------
def _array(path, obj, key, shape, allow_none=False):
    """Fetch ``obj[key]`` as a float array of ``shape`` (None = any size on that axis)."""
    if key not in obj:
        raise InputError(f"{path}: is missing the key '{key}'")
    try:
        a = (
            np.array(obj[key], dtype=float)
            if not allow_none
            else np.array(_none_to_nan(obj[key]), dtype=float)
        )
    except (TypeError, ValueError) as exc:
        raise InputError(f"{path}: '{key}' is not an array of numbers") from exc
    if a.ndim != len(shape) or any(s is not None and a.shape[i] != s for i, s in enumerate(shape)):
        want = "x".join("?" if s is None else str(s) for s in shape)
        raise InputError(f"{path}: '{key}' has shape {list(a.shape)}, expected {want}")
    if not allow_none and not np.all(np.isfinite(a)):
        raise InputError(f"{path}: '{key}' contains NaN or infinite values")
    return a


def _none_to_nan(v):
    if isinstance(v, list):
        return [_none_to_nan(x) for x in v]
    return np.nan if v is None else v


def _section(path, obj, key, kind=dict):
    if key not in obj:
        raise InputError(f"{path}: is missing the key '{key}'")
    if not isinstance(obj[key], kind):
        raise InputError(f"{path}: '{key}' must be a JSON {kind.__name__}")
    return obj[key]


def state_from_dict(data: dict, path: str | Path = "<state>") -> FitState:
    """Validate a parsed ``fit.json`` object and build the state (InputError naming
    ``path`` on any problem)."""
    if not isinstance(data, dict):
        raise InputError(f"{path}: must hold one JSON object")
    fmt = data.get("format")
    if fmt != FORMAT:
        raise InputError(
            f"{path}: is not a Somacap fitted state (format is {fmt!r}, expected {FORMAT!r})"
        )
    version = data.get("version")
    if not isinstance(version, int) or isinstance(version, bool) or version < 1:
        raise InputError(f"{path}: has no valid 'version' (a positive integer)")
    if version > VERSION:
        raise InputError(
            f"{path}: is version {version}, written by a newer Somacap "
            f"(this one reads up to version {VERSION}); please update"
        )
    for key in ("fps", "frames", "skeleton", "scales", "metaballs", "motion", "quality"):
        if key not in data:
            raise InputError(f"{path}: is missing the key '{key}'")
    try:
        fps, frames = float(data["fps"]), int(data["frames"])
    except (TypeError, ValueError) as exc:
        raise InputError(f"{path}: 'fps' and 'frames' must be numbers") from exc
    if not (math.isfinite(fps) and fps > 0) or frames < 1:
        raise InputError(f"{path}: needs fps > 0 and frames >= 1")

    skd = _section(path, data, "skeleton")
    for key in ("scale_groups", "dofs", "bones", "joints"):
        _section(path, skd, key, list)
    try:
        skel = Skeleton.from_dict(skd)
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise InputError(f"{path}: the skeleton is malformed ({exc!r})") from exc
    problem = skel.validate()
    if problem:
        raise InputError(f"{path}: the skeleton is inconsistent: {problem}")
    missing = [j for j in JOINTS if j not in skel.joint_names]
    if missing:
        raise InputError(f"{path}: the skeleton lacks the joints {missing}")
    n, G = skel.n_dof, skel.n_groups

    s = _array(path, data, "scales", (G,))
    mb = _section(path, data, "metaballs")
    items = _section(path, mb, "items", list)
    try:
        balls = Metaballs.from_dict(items, skel)
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise InputError(f"{path}: the metaballs are malformed ({exc!r})") from exc
    if not (
        np.all(np.isfinite(balls.radii))
        and np.all(balls.radii > 0)
        and np.all(np.isfinite(balls.center0))
    ):
        raise InputError(f"{path}: metaball radii must be positive finite numbers")
    vs = balls.visible_scale
    if vs is not None and not (
        vs.shape == balls.radii.shape and np.all(np.isfinite(vs)) and np.all(vs > 0)
    ):
        raise InputError(
            f"{path}: metaball visible_scale must be 3 positive finite numbers for every metaball"
        )

    motion = _section(path, data, "motion")
    names = motion.get("dof_names")
    if names is not None and list(names) != list(skel.dof_names):
        raise InputError(f"{path}: motion.dof_names does not match the skeleton's DOFs")
    root = _array(path, motion, "root_xyz", (frames, 3))
    theta = _array(path, motion, "theta", (frames, n))

    qd = _section(path, data, "quality")
    rmse = _array(path, qd, "rmse_m", (frames,), allow_none=True)
    sig = _array(path, qd, "theta_sigma", (frames, n), allow_none=True)
    flags = {}
    for key in ("converged", "diverged"):
        v = _section(path, qd, key, list)
        if len(v) != frames or not all(isinstance(x, bool) for x in v):
            raise InputError(f"{path}: quality.{key} must be {frames} true/false values")
        flags[key] = np.array(v, dtype=bool)
    cams = qd.get("cameras", [{} for _ in range(frames)])
    if not isinstance(cams, list) or len(cams) != frames:
        raise InputError(f"{path}: quality.cameras must list one object per frame")
    unobs = None
    if "unobserved" in qd:
        v = qd["unobserved"]
        if (
            not isinstance(v, list)
            or len(v) != frames
            or not all(
                isinstance(r, list) and len(r) == n and all(isinstance(x, bool) for x in r)
                for r in v
            )
        ):
            raise InputError(
                f"{path}: quality.unobserved must be {frames} lists of {n} true/false values"
            )
        unobs = np.array(v, dtype=bool).reshape(frames, n)

    override = None
    if "joints_override" in data:
        override = _array(path, data, "joints_override", (frames, len(skel.joint_names), 3))
    return FitState(
        skeleton=skel,
        s=s,
        metaballs=balls,
        root_xyz=root,
        theta=theta,
        quality=Quality(
            rmse_m=rmse,
            theta_sigma=sig,
            converged=flags["converged"],
            diverged=flags["diverged"],
            cameras=cams,
            unobserved=unobs,
        ),
        fps=fps,
        source_scene=str(data.get("source_scene", "")),
        metaball_model=str(mb.get("model", "")),
        joints_override=override,
    )


def read_state(path: str | Path) -> FitState:
    """Read and validate ``fit.json``; bad input raises InputError naming the file."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: fitted-state file not found")
    try:
        data = json.loads(path.read_text(encoding="utf-8"), parse_constant=lambda c: float("nan"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not valid JSON ({exc})") from exc
    return state_from_dict(data, path)
