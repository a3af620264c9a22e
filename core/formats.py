"""Other calibration formats: Qualisys ``.qca.txt``, OpenCV YAML, checkerboard images.

(``calibration.toml`` of anipose/Pose2Sim is :mod:`core.calibration_io`.)

Qualisys (``Calib.qca.txt``, XML): per camera ``<transform>`` with ``r11..r33`` and the
camera position ``x, y, z`` in millimetres, ``<intrinsic>`` with focal lengths and the
principal point in sensor sub-pixel units (1/64 pixel).  The rotation matrix maps
world to a camera frame that looks along −z with y up; OpenCV's frame is that one
turned 180° about x, so ``R = diag(1, -1, -1) · [r_ij]`` and ``t = -R · position``.
(Checked on the shared Pose2Sim capture: with this convention the four optical axes
meet within 0.1 m, about 3.5 m in front of every camera; the other readings leave the
cameras pointing away from each other or missing each other by metres.)
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import cv2
import numpy as np

from .camera import Camera
from .errors import InputError

_FLIP = np.diag([1.0, -1.0, -1.0])


def read_qca(path: str | Path, binning: int = 1) -> list[Camera]:
    """Cameras from a Qualisys ``.qca.txt`` calibration (metres, pixels, OpenCV frame).

    ``binning`` divides pixel quantities (Pose2Sim's ``binning_factor``).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: calibration file not found")
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise InputError(f"{path}: not a valid Qualisys XML calibration ({exc})") from exc
    cams = []
    for el in root.iter("camera"):
        name = el.get("serial", f"cam{len(cams) + 1:02d}")
        tr, it, fov = el.find("transform"), el.find("intrinsic"), el.find("fov_video")
        for tag, node in (("transform", tr), ("intrinsic", it), ("fov_video", fov)):
            if node is None:
                raise InputError(f"{path}: camera {name} is missing <{tag}>")
        try:
            M = np.array([[float(tr.attrib[f"r{i}{j}"]) for j in (1, 2, 3)] for i in (1, 2, 3)])
            pos = np.array([float(tr.attrib[k]) for k in "xyz"]) / 1000.0
            a = it.attrib
            fu, fv = float(a["focalLengthU"]), float(a["focalLengthV"])
            cu, cv = float(a["centerPointU"]), float(a["centerPointV"])
            dist = [
                float(a["radialDistortion1"]),
                float(a["radialDistortion2"]),
                float(a["tangentalDistortion1"]),
                float(a["tangentalDistortion2"]),
                float(a["radialDistortion3"]),
            ]
            w = int(fov.attrib["right"]) - int(fov.attrib["left"]) + 1
            h = int(fov.attrib["bottom"]) - int(fov.attrib["top"]) + 1
        except KeyError as exc:
            raise InputError(f"{path}: camera {name} is missing the key {exc}") from exc
        s = 64.0 * binning
        K = np.array([[fu / s, 0.0, cu / s], [0.0, fv / s, cv / s], [0.0, 0.0, 1.0]])
        R = _FLIP @ M
        cams.append(Camera(name, (w // binning, h // binning), K, np.array(dist), R, -R @ pos))
    if not cams:
        raise InputError(f"{path}: no <camera> found")
    return cams


_YAML_KEYS = {
    "K": ("camera_matrix", "K", "cameraMatrix"),
    "dist": ("distortion_coefficients", "dist_coeffs", "D", "distCoeffs", "dist"),
    "R": ("R", "rotation_matrix", "rvec", "rotation"),
    "t": ("T", "t", "tvec", "translation"),
}


def read_opencv_yaml(path: str | Path, name: str | None = None) -> Camera:
    """One camera from an OpenCV ``FileStorage`` YAML/XML file.

    Keys: ``image_width``/``image_height`` (or ``size``), the camera matrix
    (``camera_matrix``/``K``), distortion (``distortion_coefficients``/``D``, optional),
    rotation (3×3 ``R`` or Rodrigues ``rvec``) and translation (``T``/``tvec``, metres),
    world -> camera.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: calibration file not found")
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    if not fs.isOpened():
        raise InputError(f"{path}: cannot be read by OpenCV FileStorage")
    try:

        def node(kind, required=True):
            for key in _YAML_KEYS[kind]:
                n = fs.getNode(key)
                if not n.empty():
                    return (
                        n.mat()
                        if n.isMap() or n.isSeq() is False
                        else np.array([n.at(i).real() for i in range(n.size())])
                    )
            if required:
                raise InputError(f"{path}: is missing the key '{_YAML_KEYS[kind][0]}'")
            return None

        K = node("K")
        dist = node("dist", required=False)
        R = node("R")
        t = node("t")
        w, h = fs.getNode("image_width"), fs.getNode("image_height")
        if not w.empty() and not h.empty():
            size = (int(w.real()), int(h.real()))
        elif not fs.getNode("size").empty():
            sz = fs.getNode("size")
            size = (int(sz.at(0).real()), int(sz.at(1).real()))
        else:
            raise InputError(f"{path}: is missing the key 'image_width'")
    finally:
        fs.release()
    R = np.asarray(R, dtype=float)
    if R.size == 3:
        R = cv2.Rodrigues(R.reshape(3))[0]
    if K is None or np.asarray(K).shape != (3, 3) or R.shape != (3, 3):
        raise InputError(f"{path}: camera matrix and rotation must be 3x3")
    return Camera(
        name or path.stem,
        size,
        K,
        np.zeros(5) if dist is None else dist,
        R,
        np.asarray(t, dtype=float).reshape(3),
    )


def write_opencv_yaml(path: str | Path, cam: Camera) -> Path:
    """Write one camera as OpenCV ``FileStorage`` YAML (the keys :func:`read_opencv_yaml` reads)."""
    path = Path(path)
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", int(cam.size[0]))
    fs.write("image_height", int(cam.size[1]))
    fs.write("camera_matrix", cam.K)
    fs.write("distortion_coefficients", cam.dist.reshape(1, 5))
    fs.write("R", cam.R)
    fs.write("T", cam.t.reshape(3, 1))
    fs.release()
    return path


def checkerboard_intrinsics(images: list[str | Path], corners: tuple[int, int], square_m: float):
    """Intrinsics from checkerboard images with ``cv2.calibrateCamera``.

    Parameters
    ----------
    images : list of paths
    corners : (rows, cols) of inner corners (Pose2Sim's ``intrinsics_corners_nb``; the
        order is tried both ways).
    square_m : float
        Square size, metres.

    Returns
    -------
    K (3, 3), dist (5,), rms (px), size (w, h), number of images used.
    """
    obj, img_pts, size = [], [], None
    pattern = None
    for p in images:
        img = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise InputError(f"{p}: cannot be read as an image")
        size = (img.shape[1], img.shape[0])
        for pat in [pattern] if pattern else [tuple(corners), tuple(corners)[::-1]]:
            ok, c = cv2.findChessboardCorners(
                img, pat, cv2.CALIB_CB_ADAPTIVE_THRESH + cv2.CALIB_CB_NORMALIZE_IMAGE
            )
            if ok:
                pattern = pat
                c = cv2.cornerSubPix(
                    img,
                    c,
                    (5, 5),
                    (-1, -1),
                    (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4),
                )
                grid = np.zeros((pat[0] * pat[1], 3), np.float32)
                grid[:, :2] = np.mgrid[0 : pat[0], 0 : pat[1]].T.reshape(-1, 2) * square_m
                obj.append(grid)
                img_pts.append(c)
                break
    if len(obj) < 3:
        raise InputError(
            f"{Path(images[0]).parent if images else '?'}: the checkerboard was "
            f"found in only {len(obj)} images (need 3)"
        )
    rms, K, dist, _, _ = cv2.calibrateCamera(obj, img_pts, size, None, None)
    return K, dist.ravel()[:5], float(rms), size, len(obj)
