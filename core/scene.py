"""Scene folders: what a capture is on disk (SPEC.md, "A scene folder").

::

    scene.toml          name, fps, frames, cameras, size, field, [source], optional [truth]
    calibration.toml    cameras (see :mod:`core.calibration_io`)
    images/<cam>/000000.png ...   or  videos/<cam>.mp4
    wand/<cam>/000000.png ...     optional reference-bar sequence, with wand.toml (length_m)
    clicks.json         optional {"frame": 0, "joints": {"<joint>": {"<cam>": [u, v]}}}
    truth.npz           optional ground truth of synthetic scenes (see :data:`TRUTH_KEYS`)

Images are returned as the pipeline sees them: for ``field = "odd"`` only rows
0, 2, 4, ... (the odd lines counted from 1) are kept, for ``"even"`` rows 1, 3, ...;
``calibration.toml`` then describes that half-height image (pixel aspect 2).
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import dataclass
from dataclasses import field as dc_field
from functools import cached_property
from pathlib import Path

import cv2
import numpy as np

from .calibration_io import read_calibration
from .camera import Camera
from .errors import InputError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv")

#: Arrays in ``truth.npz`` (F frames, J joints, B bones, V vertices, C cameras).
TRUTH_KEYS = {
    "joint_names": "(J,) str — names from core.landmarks.JOINTS",
    "joints_xyz": "(F, J, 3) float — joint world positions, metres",
    "bone_names": "(B,) str — the character's deforming bones",
    "bone_parents": "(B,) int — parent index, -1 for the root",
    "bone_matrices": "(F, B, 4, 4) float — bone world matrices (head at the origin, Y along)",
    "vertices": "(F, V, 3) float32 — rendered mesh vertices, world metres",
    "faces": "(T, 3) int — mesh triangles (indices into V)",
    "masks": "(C, F, H, W) bool — per-camera foreground masks (packed with np.packbits on W)",
    "camera_names": "(C,) str — camera order of masks",
    "height_m": "() float — body height (rest), metres",
    "frame_times": "(F,) float — capture time of each frame, seconds",
}


@dataclass
class Scene:
    """A loaded, validated scene folder.

    Attributes
    ----------
    root : Path
        The scene folder.
    name : str
    fps : float
    n_frames : int
    cameras : list of str
        Camera names, in the order of every per-camera array.
    size : tuple of int
        ``(width, height)`` of the stored images, pixels.
    field : str
        ``"none"``, ``"odd"`` or ``"even"``.
    meta : dict
        The whole parsed ``scene.toml``.
    """

    root: Path
    name: str
    fps: float
    n_frames: int
    cameras: list[str]
    size: tuple[int, int]
    field: str = "none"
    meta: dict = dc_field(default_factory=dict)
    camera_sizes: dict = dc_field(default_factory=dict)
    _sources: dict = dc_field(default_factory=dict, repr=False)
    _video_cache: dict = dc_field(default_factory=dict, repr=False)

    # -- images -----------------------------------------------------------------
    @property
    def image_size(self) -> tuple[int, int]:
        """``(width, height)`` of the images as the pipeline sees them (after field)."""
        w, h = self.size
        if self.field == "none":
            return w, h
        return w, (h + (1 if self.field == "odd" else 0)) // 2

    def camera_size(self, cam: str) -> tuple[int, int]:
        """``(width, height)`` of one camera's images as the pipeline sees them.

        Equal to :attr:`image_size` except for videos whose frames differ in size.
        """
        w, h = self.camera_sizes.get(cam, self.size)
        if self.field == "none":
            return w, h
        return w, (h + (1 if self.field == "odd" else 0)) // 2

    def _apply_field(self, img: np.ndarray) -> np.ndarray:
        if self.field == "odd":
            return img[0::2]
        if self.field == "even":
            return img[1::2]
        return img

    def image(self, cam: str | int, frame: int, color: bool = False) -> np.ndarray:
        """One image as uint8: grey ``(H, W)`` or RGB ``(H, W, 3)`` when ``color``."""
        cam = self.cameras[cam] if isinstance(cam, int) else cam
        if not 0 <= frame < self.n_frames:
            raise IndexError(f"frame {frame} outside 0..{self.n_frames - 1}")
        src = self._sources[cam]
        if isinstance(src, list):
            img = cv2.imread(str(src[frame]), cv2.IMREAD_COLOR)
            if img is None:
                raise InputError(f"{src[frame]}: cannot be read as an image")
        else:
            img = self._video_frames(cam)[frame]
        img = self._apply_field(img)
        if color:
            return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
        return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)

    def _video_frames(self, cam: str) -> list[np.ndarray]:
        if cam not in self._video_cache:
            self._video_cache[cam] = _read_video(self._sources[cam])
        return self._video_cache[cam]

    # -- side files ---------------------------------------------------------------
    @property
    def calibration_path(self) -> Path:
        return self.root / "calibration.toml"

    def calibration(self, path: str | Path | None = None) -> list[Camera]:
        """Cameras from ``calibration.toml`` (or ``path``), in the scene's camera order."""
        path = Path(path) if path is not None else self.calibration_path
        cams = {c.name: c for c in read_calibration(path)}
        missing = [c for c in self.cameras if c not in cams]
        if missing:
            raise InputError(
                f"{path}: has cameras {sorted(cams)} but the scene needs {self.cameras} "
                f"(missing {missing})"
            )
        out = [cams[c] for c in self.cameras]
        for c in out:
            if tuple(c.size) != tuple(self.camera_size(c.name)):
                raise InputError(
                    f"{path}: camera {c.name} has size {list(c.size)} but its images are "
                    f"{list(self.camera_size(c.name))}"
                )
        return out

    @property
    def has_truth(self) -> bool:
        return (self.root / "truth.npz").is_file()

    @cached_property
    def truth(self) -> dict[str, np.ndarray]:
        """Ground truth arrays (see :data:`TRUTH_KEYS`); masks are unpacked lazily."""
        path = self.root / "truth.npz"
        if not path.is_file():
            raise InputError(f"{path}: no ground truth in this scene")
        try:
            with np.load(path, allow_pickle=False) as z:
                return {k: z[k] for k in z.files}
        except (OSError, ValueError) as exc:
            raise InputError(f"{path}: cannot be read as .npz ({exc})") from exc

    def truth_masks(self) -> np.ndarray:
        """Foreground masks ``(C, F, H, W)`` bool from ``truth.npz``."""
        packed = self.truth["masks"]
        w = self.image_size[0]
        return np.unpackbits(packed, axis=-1, count=w).astype(bool)

    def clicks(self) -> dict:
        """``clicks.json`` as ``{"frame": int, "joints": {joint: {cam: (u, v)}}}``."""
        path = self.root / "clicks.json"
        if not path.is_file():
            raise InputError(f"{path}: no key-joint clicks in this scene")
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except json.JSONDecodeError as exc:
            raise InputError(f"{path}: not valid JSON ({exc})") from exc
        if not isinstance(data, dict) or "joints" not in data:
            raise InputError(f"{path}: needs a 'joints' object")
        joints = {}
        for joint, per_cam in data["joints"].items():
            if not isinstance(per_cam, dict):
                raise InputError(f"{path}: joint '{joint}' must map camera names to [u, v]")
            joints[joint] = {}
            for cam, uv in per_cam.items():
                if cam not in self.cameras:
                    raise InputError(f"{path}: joint '{joint}' names unknown camera '{cam}'")
                uv = np.asarray(uv, dtype=float)
                if uv.shape != (2,) or not np.all(np.isfinite(uv)):
                    raise InputError(f"{path}: joint '{joint}' in {cam} is not [u, v]")
                joints[joint][cam] = uv
        return {"frame": int(data.get("frame", 0)), "joints": joints}

    # -- wand -----------------------------------------------------------------------
    @property
    def has_wand(self) -> bool:
        return (self.root / "wand").is_dir()

    def wand_length(self) -> float:
        """Reference-bar length in metres from ``wand.toml``."""
        path = self.root / "wand.toml"
        data = _read_toml(path)
        if "length_m" not in data:
            raise InputError(f"{path}: is missing the key 'length_m'")
        length = float(data["length_m"])
        if not length > 0:
            raise InputError(f"{path}: length_m must be positive, got {length}")
        return length

    def wand_frames(self) -> dict[str, list[Path]]:
        """Wand image paths per camera (same count everywhere, checked)."""
        root = self.root / "wand"
        return _image_folders(root, self.cameras, "wand")

    def wand_image(self, cam: str | int, frame: int) -> np.ndarray:
        """One wand image as grey uint8 ``(H, W)``, field applied like :meth:`image`."""
        cam = self.cameras[cam] if isinstance(cam, int) else cam
        path = self.wand_frames()[cam][frame]
        img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise InputError(f"{path}: cannot be read as an image")
        return self._apply_field(img)


def _read_toml(path: Path) -> dict:
    if not path.is_file():
        raise InputError(f"{path}: file not found")
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a valid TOML file ({exc})") from exc


def _image_folders(root: Path, cameras: list[str], what: str) -> dict[str, list[Path]]:
    out = {}
    for cam in cameras:
        folder = root / cam
        if not folder.is_dir():
            raise InputError(f"{folder}: missing {what} folder for camera {cam}")
        files = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not files:
            raise InputError(f"{folder}: holds no images")
        out[cam] = files
    counts = {cam: len(f) for cam, f in out.items()}
    if len(set(counts.values())) > 1:
        first = cameras[0]
        for cam in cameras[1:]:
            if counts[cam] != counts[first]:
                raise InputError(
                    f"{root / cam}: {cam} has {counts[cam]} frames, {first} has {counts[first]}: "
                    "every camera needs the same frame count"
                )
    return out


def _read_video(path: Path) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise InputError(f"{path}: cannot be opened as a video")
    frames = []
    try:
        while True:
            ok, img = cap.read()
            if not ok:
                break
            frames.append(img)
    finally:
        cap.release()
    if not frames:
        raise InputError(f"{path}: holds no frames")
    return frames


def _video_info(path: Path) -> tuple[int, tuple[int, int]]:
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise InputError(f"{path}: cannot be opened as a video")
    try:
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        size = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
    finally:
        cap.release()
    return n, size


def load_scene(path: str | Path, check_images: bool = True) -> Scene:
    """Load and validate a scene folder.

    Checks that ``scene.toml`` exists and names its cameras, that every camera has
    an image folder (or a video) with the same frame count as the others and as
    ``scene.toml`` says, and that the first image's size matches.  Raises
    :class:`~core.errors.InputError` naming the offending file.
    """
    root = Path(path)
    if not root.is_dir():
        raise InputError(f"{root}: scene folder not found")
    toml_path = root / "scene.toml"
    meta = _read_toml(toml_path)
    for key in ("cameras",):
        if key not in meta:
            raise InputError(f"{toml_path}: is missing the key '{key}'")
    cameras = [str(c) for c in meta["cameras"]]
    if len(cameras) < 1 or len(set(cameras)) != len(cameras):
        raise InputError(f"{toml_path}: 'cameras' must list distinct camera names")
    fld = str(meta.get("field", "none"))
    if fld not in ("none", "odd", "even"):
        raise InputError(f"{toml_path}: field must be none, odd or even, got '{fld}'")

    sources: dict = {}
    img_root, vid_root = root / "images", root / "videos"
    for cam in cameras:
        folder = img_root / cam
        videos = [vid_root / f"{cam}{s}" for s in VIDEO_SUFFIXES]
        video = next((v for v in videos if v.is_file()), None)
        if folder.is_dir():
            sources[cam] = None  # filled below, with the frame-count check
        elif video is not None:
            sources[cam] = video
        else:
            raise InputError(f"{folder}: missing image folder (or videos/{cam}.mp4) for {cam}")
    folder_cams = [c for c in cameras if sources[c] is None]
    if folder_cams:
        sources.update(_image_folders(img_root, folder_cams, "image"))

    counts, sizes = {}, {}
    for cam in cameras:
        src = sources[cam]
        if isinstance(src, list):
            counts[cam] = len(src)
            if check_images:
                img = cv2.imread(str(src[0]), cv2.IMREAD_UNCHANGED)
                if img is None:
                    raise InputError(f"{src[0]}: cannot be read as an image")
                sizes[cam] = (img.shape[1], img.shape[0])
        else:
            counts[cam], sizes[cam] = _video_info(src)
    first = cameras[0]
    for cam in cameras:
        if counts[cam] != counts[first]:
            raise InputError(
                f"{root}: {cam} has {counts[cam]} frames, {first} has {counts[first]}: "
                "every camera needs the same frame count"
            )
    n_frames = counts[first]
    if "frames" in meta and int(meta["frames"]) != n_frames:
        raise InputError(
            f"{toml_path}: says {int(meta['frames'])} frames but the images hold {n_frames}"
        )
    if "size" in meta:
        size = (int(meta["size"][0]), int(meta["size"][1]))
    elif sizes:
        size = sizes[first]
    else:
        raise InputError(f"{toml_path}: is missing the key 'size'")
    for cam, s in sizes.items():
        if "size" in meta and tuple(s) != size and not isinstance(sources[cam], Path):
            raise InputError(
                f"{root}: images of {cam} are {list(s)} but scene.toml says {list(size)}"
            )
    return Scene(
        root=root,
        name=str(meta.get("name", root.name)),
        fps=float(meta.get("fps", 25.0)),
        n_frames=n_frames,
        cameras=cameras,
        size=size,
        field=fld,
        meta=meta,
        camera_sizes=sizes,
        _sources=sources,
    )


def load_wand(path: str | Path) -> Scene:
    """Load a scene folder that may hold only a wand sequence (``wand/``, ``wand.toml``).

    A full scene (``scene.toml`` with ``images/`` or ``videos/``) is loaded by
    :func:`load_scene` without reading images; otherwise the cameras come from
    ``scene.toml`` or, without one, the folder names under ``wand/``, and the size from
    the first wand image.  ``n_frames`` is 0 (no capture images).
    """
    root = Path(path)
    if not root.is_dir():
        raise InputError(f"{root}: scene folder not found")
    if (root / "scene.toml").is_file() and (
        (root / "images").is_dir() or (root / "videos").is_dir()
    ):
        return load_scene(root, check_images=False)
    wand = root / "wand"
    if not wand.is_dir():
        raise InputError(f"{wand}: the scene has no wand sequence")
    meta = _read_toml(root / "scene.toml") if (root / "scene.toml").is_file() else {}
    cameras = [
        str(c) for c in meta.get("cameras", sorted(p.name for p in wand.iterdir() if p.is_dir()))
    ]
    if not cameras:
        raise InputError(f"{wand}: holds no camera folders")
    fld = str(meta.get("field", "none"))
    if fld not in ("none", "odd", "even"):
        raise InputError(f"{root / 'scene.toml'}: field must be none, odd or even, got '{fld}'")
    files = _image_folders(wand, cameras, "wand")
    img = cv2.imread(str(files[cameras[0]][0]), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InputError(f"{files[cameras[0]][0]}: cannot be read as an image")
    return Scene(
        root=root,
        name=str(meta.get("name", root.name)),
        fps=float(meta.get("fps", 25.0)),
        n_frames=0,
        cameras=cameras,
        size=(img.shape[1], img.shape[0]),
        field=fld,
        meta=meta,
    )
