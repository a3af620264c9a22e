"""Camera-rig presets and framing (numpy, no bpy).

Cameras are placed around the motion's bounding volume in a frame fitted to the take:
``e1`` the main horizontal direction of travel, ``e2`` perpendicular to it (horizontal),
``z`` up.  The focal length of each camera is the largest that keeps every vertex of
the take inside the image with a margin, so the person is as large as possible.
"""

from __future__ import annotations

import numpy as np

from core.camera import Camera

RIGS = ("line3", "orthogonal3", "ring4", "ring8")


def look_at(center: np.ndarray, target: np.ndarray, up_hint=(0.0, 0.0, 1.0)) -> np.ndarray:
    """World -> OpenCV camera rotation (3, 3) for a camera at ``center`` looking at ``target``."""
    z = np.asarray(target, float) - np.asarray(center, float)
    z /= np.linalg.norm(z)
    up = np.asarray(up_hint, float)
    if abs(np.dot(up, z)) > 0.999:
        up = np.array([0.0, 1.0, 0.0])
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z])


def motion_frame(root_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit horizontal axes ``(e1, e2)`` (3,): main travel direction and its normal."""
    d = root_xy - root_xy.mean(axis=0)
    if np.allclose(d, 0):
        e1 = np.array([1.0, 0.0])
    else:
        _, _, vt = np.linalg.svd(d, full_matrices=False)
        e1 = vt[0]
    if e1[0] < 0:
        e1 = -e1
    e1 = np.array([e1[0], e1[1], 0.0])
    e2 = np.array([-e1[1], e1[0], 0.0])
    return e1, e2


def rig_poses(
    rig: str, center: np.ndarray, e1: np.ndarray, e2: np.ndarray, distance: float
) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """``[(name, R, C)]``: world->camera rotation and camera centre for each camera."""
    z = np.array([0.0, 0.0, 1.0])
    eye = center.copy()
    out = []
    if rig == "line3":
        # Three converging cameras on a line in front of the travel path (paper 1).
        for k, side in enumerate((-1, 0, 1)):
            C = center - distance * e2 + side * 0.35 * distance * e1 + 0.1 * z
            out.append((f"cam{k + 1:02d}", look_at(C, eye), C))
    elif rig == "orthogonal3":
        # Front (across the path), side (along the path), overhead: mutually orthogonal axes.
        C = center - distance * e2
        out.append(("cam01", look_at(C, eye), C))
        C = center - distance * e1
        out.append(("cam02", look_at(C, eye), C))
        C = center + distance * z
        out.append(("cam03", look_at(C, eye, up_hint=e2), C))
    elif rig in ("ring4", "ring8"):
        n = int(rig[4:])
        for k in range(n):
            a = 2 * np.pi * k / n
            d = -np.cos(a) * e2 + np.sin(a) * e1
            C = center + distance * d + 0.25 * z
            out.append((f"cam{k + 1:02d}", look_at(C, eye), C))
    else:
        raise ValueError(f"unknown rig {rig!r}; choose one of {RIGS}")
    return out


def frame_cameras(
    rig: str,
    xyz: np.ndarray,
    root_xy: np.ndarray,
    size: tuple[int, int],
    margin: float = 0.04,
    distance: float | None = None,
) -> list[Camera]:
    """Cameras of a rig preset framing the points ``xyz`` (N, 3) of the whole take.

    The principal point is the image centre; each camera's focal length (square pixels)
    is the largest that keeps all points inside the image minus ``margin`` (fraction of
    the size) on every side.
    """
    w, h = size
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    center = (lo + hi) / 2
    e1, e2 = motion_frame(root_xy)
    if distance is None:
        distance = max(6.0, 2.0 * float(np.linalg.norm(hi - lo)))
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    cams = []
    for name, R, C in rig_poses(rig, center, e1, e2, distance):
        pc = (xyz - C) @ R.T
        x, y = pc[:, 0] / pc[:, 2], pc[:, 1] / pc[:, 2]
        f = min(
            (w / 2 * (1 - 2 * margin)) / np.abs(x).max(),
            (h / 2 * (1 - 2 * margin)) / np.abs(y).max(),
        )
        K = np.array([[f, 0, cx], [0, f, cy], [0, 0, 1.0]])
        cams.append(Camera(name, (w, h), K, np.zeros(5), R, -R @ C))
    return cams
