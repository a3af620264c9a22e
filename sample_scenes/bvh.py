"""Read a BVH motion-capture file and evaluate its skeleton (numpy, no bpy).

Frames and units
----------------
BVH files are Y up with the subject facing +Z; everything returned here is already in
the Blender world (Z up, facing -Y, metres): ``xyz_blender = AXES @ xyz_bvh * scale``,
the same convention as Blender's own BVH importer (forward -Z, up Y).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from core.errors import InputError

#: BVH (Y up, facing +Z) -> Blender world (Z up, facing -Y): (x, y, z) -> (x, -z, y).
AXES = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])

#: CMU units -> metres.
CMU_SCALE = 0.056444

_ROT = {"Xrotation": 0, "Yrotation": 1, "Zrotation": 2}
_POS = {"Xposition": 0, "Yposition": 1, "Zposition": 2}


@dataclass
class Bvh:
    """A parsed BVH clip.

    Attributes
    ----------
    path : Path
    names : list of str
        Joint names, parents before children.
    parents : ndarray (J,) int
        Parent index, -1 for the root.
    offsets : ndarray (J, 3)
        Joint offset from its parent, Blender world axes, metres.
    ends : ndarray (J, 3)
        Offset of the joint's "bone end": its first child's offset, or its End Site
        (zeros when the joint has neither), Blender axes, metres.
    channels : list of list of str
        Channel names per joint.
    motion : ndarray (N, K)
        Raw channel values per BVH frame.
    frame_time : float
        Seconds per BVH frame.
    """

    path: Path
    names: list
    parents: np.ndarray
    offsets: np.ndarray
    ends: np.ndarray
    channels: list
    motion: np.ndarray
    frame_time: float

    @property
    def n_frames(self) -> int:
        return int(self.motion.shape[0])

    def index(self, name: str) -> int:
        return self.names.index(name)

    def children(self, j: int) -> list[int]:
        return [int(c) for c in np.flatnonzero(self.parents == j)]

    def local_rotations(self) -> np.ndarray:
        """Per-frame local rotations ``(N, J, 3, 3)`` in Blender axes."""
        n, nj = self.n_frames, len(self.names)
        R = np.broadcast_to(np.eye(3), (n, nj, 3, 3)).copy()
        col = 0
        for j, chans in enumerate(self.channels):
            for c in chans:
                if c in _ROT:
                    R[:, j] = R[:, j] @ _axis_rotation(_ROT[c], np.radians(self.motion[:, col]))
                col += 1
        return AXES @ R @ AXES.T

    def root_positions(self, scale: float) -> np.ndarray:
        """Per-frame root translation channels ``(N, 3)``, Blender axes, metres."""
        p = np.zeros((self.n_frames, 3))
        col = 0
        for c in self.channels[0]:
            if c in _POS:
                p[:, _POS[c]] = self.motion[:, col]
            col += 1
        return (p * scale) @ AXES.T + self.offsets[0]

    def sample(self, times: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
        """World rotations and positions of every joint at ``times`` (seconds from frame 0).

        Local rotations are slerped and the root translation interpolated linearly
        between the neighbouring BVH frames.

        Returns
        -------
        G : ndarray (T, J, 3, 3)
            Joint world rotations (identity = the BVH rest pose).
        xyz : ndarray (T, J, 3)
            Joint world positions, metres.
        """
        times = np.asarray(times, dtype=float)
        x = np.clip(times / self.frame_time, 0.0, self.n_frames - 1.0)
        i0 = np.minimum(np.floor(x).astype(int), self.n_frames - 1)
        i1 = np.minimum(i0 + 1, self.n_frames - 1)
        a = x - i0
        loc = self.local_rotations()
        q = _slerp(_mat_to_quat(loc[i0]), _mat_to_quat(loc[i1]), a[:, None])
        local = _quat_to_mat(q)
        root = self.root_positions(scale)
        root = root[i0] * (1 - a[:, None]) + root[i1] * a[:, None]
        return _forward(local, root, self.offsets * scale, self.parents)


def _forward(local, root, offsets, parents):
    t, nj = local.shape[:2]
    G = np.empty_like(local)
    xyz = np.empty((t, nj, 3))
    for j in range(nj):
        p = parents[j]
        if p < 0:
            G[:, j] = local[:, j]
            xyz[:, j] = root
        else:
            G[:, j] = G[:, p] @ local[:, j]
            xyz[:, j] = xyz[:, p] + G[:, p] @ offsets[j]
    return G, xyz


def _axis_rotation(axis: int, angle: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    R = np.zeros(angle.shape + (3, 3))
    i, k = [(1, 2), (2, 0), (0, 1)][axis]
    R[..., axis, axis] = 1.0
    R[..., i, i] = c
    R[..., k, k] = c
    R[..., i, k] = -s
    R[..., k, i] = s
    return R


def _mat_to_quat(R: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> unit quaternions (..., 4) as (w, x, y, z)."""
    from scipy.spatial.transform import Rotation

    shape = R.shape[:-2]
    xyzw = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat()
    return np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=1).reshape(shape + (4,))


def _quat_to_mat(q: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    shape = q.shape[:-1]
    q = q.reshape(-1, 4)
    return (
        Rotation.from_quat(np.concatenate([q[:, 1:], q[:, :1]], axis=1))
        .as_matrix()
        .reshape(shape + (3, 3))
    )


def _slerp(q0: np.ndarray, q1: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Batched spherical interpolation of unit quaternions (..., 4); ``a`` broadcasts."""
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)
    dot = np.abs(dot)
    a = np.asarray(a)[..., None]
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin = np.sin(theta)
    small = sin < 1e-6
    safe = np.where(small, 1.0, sin)
    w0 = np.where(small, 1 - a, np.sin((1 - a) * theta) / safe)
    w1 = np.where(small, a, np.sin(a * theta) / safe)
    q = w0 * q0 + w1 * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def read_bvh(path: str | Path) -> Bvh:
    """Parse a BVH file; raise :class:`~core.errors.InputError` naming it when malformed."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: BVH file not found")
    try:
        text = path.read_text(encoding="utf-8", errors="strict")
    except (UnicodeDecodeError, OSError) as exc:
        raise InputError(f"{path}: cannot be read as a text BVH file ({exc})") from exc
    tokens = text.split()
    try:
        return _parse(path, tokens)
    except (IndexError, ValueError) as exc:
        raise InputError(f"{path}: is not a valid BVH file ({exc})") from exc


def _parse(path: Path, tok: list[str]) -> Bvh:
    if not tok or tok[0] != "HIERARCHY":
        raise ValueError("it does not start with HIERARCHY")
    names, parents, offsets, channels, ends = [], [], [], [], []
    stack: list[int] = []
    i = 1
    pending_end = False
    while tok[i] != "MOTION":
        t = tok[i]
        if t in ("ROOT", "JOINT"):
            names.append(tok[i + 1])
            parents.append(stack[-1] if stack else -1)
            offsets.append(None)
            channels.append([])
            ends.append(None)
            i += 2
        elif t == "End":
            pending_end = True
            i += 2
        elif t == "{":
            stack.append(-2 if pending_end else len(names) - 1)
            i += 1
        elif t == "}":
            stack.pop()
            pending_end = False if not stack or stack[-1] != -2 else pending_end
            i += 1
        elif t == "OFFSET":
            off = np.array([float(v) for v in tok[i + 1 : i + 4]])
            if stack[-1] == -2:
                owner = stack[-2]
                if ends[owner] is None:
                    ends[owner] = off
            else:
                j = stack[-1]
                offsets[j] = off
                p = parents[j]
                if p >= 0 and ends[p] is None:
                    ends[p] = off
            i += 4
        elif t == "CHANNELS":
            n = int(tok[i + 1])
            chans = tok[i + 2 : i + 2 + n]
            bad = [c for c in chans if c not in _ROT and c not in _POS]
            if bad:
                raise ValueError(f"unknown channel {bad[0]}")
            channels[stack[-1]] = chans
            i += 2 + n
        else:
            raise ValueError(f"unexpected token '{t}'")
    if not names or any(o is None for o in offsets):
        raise ValueError("the hierarchy has no joints or a joint without OFFSET")
    if tok[i + 1] != "Frames:" or tok[i + 3 : i + 5] != ["Frame", "Time:"]:
        raise ValueError("the MOTION header needs 'Frames:' and 'Frame Time:'")
    n_frames = int(tok[i + 2])
    frame_time = float(tok[i + 5])
    n_chan = sum(len(c) for c in channels)
    values = np.array([float(v) for v in tok[i + 6 :]])
    if n_frames < 1 or values.size != n_frames * n_chan or not frame_time > 0:
        raise ValueError(
            f"expected {n_frames} frames of {n_chan} channels, found {values.size} values"
        )
    if not np.all(np.isfinite(values)):
        raise ValueError("the motion holds NaN or inf")
    ends = [np.zeros(3) if e is None else e for e in ends]
    return Bvh(
        path=path,
        names=names,
        parents=np.array(parents),
        offsets=np.array(offsets) @ AXES.T,
        ends=np.array(ends) @ AXES.T,
        channels=channels,
        motion=values.reshape(n_frames, n_chan),
        frame_time=frame_time,
    )
