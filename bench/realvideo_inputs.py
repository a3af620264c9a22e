"""Inputs of the real-video fit benchmark (:mod:`bench.realvideo_fit`).

Clicks (``clicks.json`` layout), the videos' frame rate, the videos decoded once
(Wallis-filtered grey and RGB), the empty-scene calibration photos registered to the
video frames, and the person's region in a camera's foreground masks.  Image
coordinates: pixels, (0, 0) the centre of the top-left pixel; world Z up, metres.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from bench.realvideo import wallis
from core.camera import Camera
from core.errors import InputError

#: Frame rate of the pose2sim_single videos, frames per second.
FPS = 60.0


# -- input ----------------------------------------------------------------------------------
def load_clicks(path: Path, cameras: list[str]) -> dict:
    """``clicks.json`` (SPEC.md layout) as ``{"frame": int, "joints": {joint: {cam: uv}}}``.

    Raises
    ------
    InputError
        The file is missing, not JSON, or names a camera not in ``cameras`` or a
        position that is not ``[u, v]``.
    """
    if not path.is_file():
        raise InputError(f"{path}: clicks file not found")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON ({exc})") from exc
    if not isinstance(data, dict) or not isinstance(data.get("joints"), dict):
        raise InputError(f"{path}: needs a 'joints' object")
    joints = {}
    for joint, per_cam in data["joints"].items():
        if not isinstance(per_cam, dict):
            raise InputError(f"{path}: joint '{joint}' must map camera names to [u, v]")
        joints[joint] = {}
        for cam, uv in per_cam.items():
            if cam not in cameras:
                raise InputError(f"{path}: joint '{joint}' names unknown camera '{cam}'")
            uv = np.asarray(uv, float)
            if uv.shape != (2,) or not np.all(np.isfinite(uv)):
                raise InputError(f"{path}: joint '{joint}' in {cam} is not [u, v]")
            joints[joint][cam] = uv
    return {"frame": int(data.get("frame", 0)), "joints": joints}


def read_video(
    path: Path, size: tuple[int, int], n_frames: int, grey_scale: float | None, colour_scale: float
) -> tuple[np.ndarray | None, np.ndarray]:
    """Decode one camera once: Wallis-filtered grey frames and RGB frames.

    Frames narrower than the calibrated ``size`` (cam01/cam02: 1080 of 1088 px) are
    padded on the right, so pixel coordinates are unchanged.

    Returns
    -------
    grey : ndarray, shape (F, h, w), uint8, or None when ``grey_scale`` is None
        Wallis-filtered (:func:`bench.realvideo.wallis`) at ``grey_scale``.
    rgb : ndarray, shape (F, h', w', 3), uint8
        Colour frames at ``colour_scale``.
    """
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise InputError(f"{path}: cannot be opened as a video")
    w, h = size
    grey, rgb = [], []
    while len(rgb) < n_frames:
        ok, f = cap.read()
        if not ok:
            break
        if f.shape[0] > h or f.shape[1] > w:
            raise InputError(
                f"{path}: frame {f.shape[1]}x{f.shape[0]} is larger than the calibration {w}x{h}"
            )
        f = cv2.copyMakeBorder(f, 0, h - f.shape[0], 0, w - f.shape[1], cv2.BORDER_REPLICATE)
        if grey_scale is not None:
            g = cv2.resize(
                cv2.cvtColor(f, cv2.COLOR_BGR2GRAY),
                (round(w * grey_scale), round(h * grey_scale)),
                interpolation=cv2.INTER_AREA,
            )
            grey.append(wallis(g))
        c = cv2.resize(
            f, (round(w * colour_scale), round(h * colour_scale)), interpolation=cv2.INTER_AREA
        )
        rgb.append(cv2.cvtColor(c, cv2.COLOR_BGR2RGB))
    cap.release()
    if len(rgb) < n_frames:
        raise InputError(f"{path}: has {len(rgb)} frames, {n_frames} requested")
    return (np.stack(grey) if grey_scale is not None else None), np.stack(rgb)


def read_empty_scene(
    data: Path, name: str, size: tuple[int, int], scale: float
) -> np.ndarray | None:
    """The calibration photo of camera ``name`` (``calibration/extrinsics/<name>_ext.png``)
    registered to the video frames, RGB at ``scale``; None when absent.

    The photos are all 1088 px wide; those of the 1080-px-wide videos (cam01, cam02) were
    stretched horizontally to that width (phase correlation against the video's median
    background: 0.6–1 px shift at quarter resolution before undoing the stretch, ≤ 0.35
    px after), so they are squeezed back and padded like the video frames.
    """
    path = data / "calibration" / "extrinsics" / f"{name}_ext.png"
    img = cv2.imread(str(path))
    if img is None:
        return None
    cap = cv2.VideoCapture(str(data / "videos" / f"{name}.mp4"))
    vw = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
    cap.release()
    w, h = size
    if img.shape[1] != w or img.shape[0] != h:
        raise InputError(f"{path}: is {img.shape[1]}x{img.shape[0]}, the calibration {w}x{h}")
    if 0 < vw < w:
        img = cv2.resize(img, (vw, h), interpolation=cv2.INTER_AREA)
        img = cv2.copyMakeBorder(img, 0, 0, 0, w - vw, cv2.BORDER_REPLICATE)
    img = cv2.resize(img, (round(w * scale), round(h * scale)), interpolation=cv2.INTER_AREA)
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


# -- foreground ---------------------------------------------------------------------------
def person_region(
    camera: Camera, xyz: np.ndarray, grow: tuple[float, float] = (0.6, 0.25)
) -> tuple[int, int, int, int]:
    """Image box ``(u0, v0, u1, v1)`` around 3-D joints ``xyz`` (K, 3) projected into
    ``camera``, widened by ``grow`` (fractions of the box's width, height; at least a
    tenth of its larger side) on each side."""
    uv = camera.project(xyz)
    uv = uv[np.all(np.isfinite(uv), axis=1)]
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    ext = np.maximum((hi - lo) * np.asarray(grow), 0.1 * np.max(hi - lo))
    w, h = camera.size
    u0, v0 = np.maximum(lo - ext, 0).astype(int)
    u1, v1 = np.minimum(hi + ext, (w - 1, h - 1)).astype(int)
    return int(u0), int(v0), int(u1), int(v1)


def keep_in_region(masks: np.ndarray, box: tuple[int, int, int, int]) -> np.ndarray:
    """Keep the connected components of each mask (F, H, W) that touch ``box``."""
    u0, v0, u1, v1 = box
    out = np.zeros_like(masks)
    for f, m in enumerate(masks):
        n, lab = cv2.connectedComponents(m.astype(np.uint8), connectivity=8)
        if n <= 1:
            continue
        hit = np.unique(lab[v0 : v1 + 1, u0 : u1 + 1])
        keep = np.zeros(n, bool)
        keep[hit[hit > 0]] = True
        out[f] = keep[lab]
    return out
