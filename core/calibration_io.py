"""Read and write ``calibration.toml`` in the anipose / Pose2Sim layout.

One table per camera::

    [cam_01]
    name = "cam01"
    size = [512.0, 384.0]                   # width, height (px)
    matrix = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]
    distortions = [k1, k2, p1, p2, k3]      # OpenCV order; 4 values accepted
    rotation = [rx, ry, rz]                 # Rodrigues vector, world -> camera
    translation = [tx, ty, tz]              # metres, world -> camera
    fisheye = false

plus an optional ``[metadata]`` table.  Camera frame is OpenCV's (x right, y down,
z forward); the world is Z up, metres.  ``distortion`` is accepted as a synonym of
``distortions`` on reading.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np

from . import toml_write
from .camera import Camera, rodrigues_to_matrix
from .errors import InputError

_REQUIRED = ("size", "matrix", "rotation", "translation")


def _array(path, table, key, shape):
    try:
        a = np.asarray(table[key], dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{path}: [{table.get('name', '?')}] {key} is not numeric") from exc
    if a.shape != shape:
        raise InputError(
            f"{path}: [{table.get('name', '?')}] {key} has shape {a.shape}, expected {shape}"
        )
    if not np.all(np.isfinite(a)):
        raise InputError(f"{path}: [{table.get('name', '?')}] {key} holds NaN or inf")
    return a


def read_calibration(path: str | Path) -> list[Camera]:
    """Read cameras from an anipose/Pose2Sim ``calibration.toml``.

    Returns
    -------
    list of Camera
        In file order.  Raises :class:`~core.errors.InputError` naming the file and
        the key when the file is missing, not TOML, or a camera lacks a key.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: calibration file not found")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a valid TOML file ({exc})") from exc
    cameras = []
    for key, table in data.items():
        if key == "metadata" or not isinstance(table, dict):
            continue
        name = str(table.get("name", key))
        table = {**table, "name": name}
        for req in _REQUIRED:
            if req not in table:
                raise InputError(f"{path}: camera [{key}] is missing the key '{req}'")
        dist_key = "distortions" if "distortions" in table else "distortion"
        dist = np.asarray(table.get(dist_key, [0.0] * 5), dtype=float).ravel()
        if dist.size not in (4, 5):
            raise InputError(f"{path}: camera [{key}] {dist_key} needs 4 or 5 values")
        if table.get("fisheye", False):
            raise InputError(f"{path}: camera [{key}] is a fisheye model, which is unsupported")
        size = _array(path, table, "size", (2,))
        K = _array(path, table, "matrix", (3, 3))
        rvec = _array(path, table, "rotation", (3,))
        t = _array(path, table, "translation", (3,))
        cameras.append(
            Camera(
                name,
                (int(round(size[0])), int(round(size[1]))),
                K,
                dist,
                rodrigues_to_matrix(rvec),
                t,
            )
        )
    if not cameras:
        raise InputError(f"{path}: no camera tables found")
    return cameras


def write_calibration(
    path: str | Path, cameras: list[Camera], metadata: dict | None = None, overwrite: bool = True
) -> Path:
    """Write cameras to ``path`` in the anipose/Pose2Sim layout.

    ``overwrite=False`` refuses to replace an existing file (raises InputError).
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise InputError(f"{path}: exists already; choose another output or remove it")
    data: dict = {}
    for i, cam in enumerate(cameras):
        data[f"cam_{i:02d}"] = {
            "name": cam.name,
            "size": [float(cam.size[0]), float(cam.size[1])],
            "matrix": cam.K.tolist(),
            "distortions": cam.dist.tolist(),
            "rotation": cam.rvec.tolist(),
            "translation": cam.t.tolist(),
            "fisheye": False,
        }
    data["metadata"] = {"adjusted": False, "error": 0.0, **(metadata or {})}
    path.parent.mkdir(parents=True, exist_ok=True)
    toml_write.dump(data, path)
    return path
