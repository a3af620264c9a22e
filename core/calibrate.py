"""The calibration stage: a scene's wand sequence -> calibrated cameras and a report.

Steps: target centroids in every wand image (:mod:`core.wand`), initial orientation
from nothing but those points and the bar length (:mod:`core.orientation`), then the
self-calibrating bundle adjustment (:mod:`core.bundle`).  The adjustment's world is
the first camera's frame (OpenCV axes, metres): its datum.  Optionally (``z_up``) the
result is then expressed in a Z-up world (:func:`z_up_world`): the cameras' mean up
direction is +Z, the origin is the wand volume's centroid dropped to its lowest wand
position, +X is camera 1's x axis made horizontal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .bundle import DEFAULT_FREE, BundleResult, adjust_wand
from .camera import Camera
from .errors import InputError
from .intersect import triangulate
from .orientation import search_focal
from .progress import Progress
from .wand import WandDetections, detect_sequence


@dataclass
class CalibrationReport:
    """Calibrated cameras with the numbers that tell how good they are.

    ``bar_residual_m`` (F,): ``|A - B| - L`` of the targets intersected *independently*
    with the final cameras (not the condition residuals, which the adjustment forces
    small), NaN where not determined.  ``uv`` (F, C, 2, 2): the target points with the
    A/B labels made consistent across cameras, as adjusted (``bundle.outliers`` refers
    to them).  ``world`` says which world ``cameras`` live in; ``world_from_datum``
    (4, 4) maps the adjustment's datum frame to it (rigid, metres).
    """

    cameras: list[Camera]
    bundle: BundleResult
    detections: WandDetections
    length_m: float
    bar_residual_m: np.ndarray
    uv: np.ndarray | None = None
    world: str = "camera 1 frame (the adjustment datum)"
    world_from_datum: np.ndarray | None = None

    @property
    def bar_rms_mm(self) -> float:
        return float(1e3 * np.sqrt(np.nanmean(self.bar_residual_m**2)))

    def text(self) -> str:
        b = self.bundle
        lines = [
            f"wand: {self.detections.summary()}",
            f"bundle adjustment: {'converged' if b.success else 'NOT converged'} "
            f"({b.message}); free interior: {', '.join(b.free)}",
            f"locations used: {int(b.used.sum())}, observations flagged as bad blobs: "
            f"{int(b.outliers.sum())}, sigma0 = {b.sigma0:.3f} px",
            f"bar length L = {self.length_m * 1e3:.1f} mm; independently intersected "
            f"bars: RMS residual {self.bar_rms_mm:.3f} mm",
            "",
            f"world: {self.world}",
            f"{'camera':8s} {'RMSE px':>8s} {'f px':>10s} {'sd':>6s} {'aspect':>7s} "
            f"{'cx':>8s} {'cy':>8s} {'k1':>8s} {'k2':>8s}  centre (m)",
        ]
        for i, c in enumerate(self.cameras):
            lines.append(
                f"{c.name:8s} {b.rmse_px[i]:8.3f} {c.K[0, 0]:10.2f} {b.sigma_of(i, 'f'):6.2f} "
                f"{c.aspect:7.4f} {c.K[0, 2]:8.2f} {c.K[1, 2]:8.2f} {c.dist[0]:8.4f} "
                f"{c.dist[1]:8.4f}  [{c.center[0]:.4f}, {c.center[1]:.4f}, {c.center[2]:.4f}]"
            )
        return "\n".join(lines)

    def metadata(self) -> dict:
        return {
            "adjusted": True,
            "error": float(self.bundle.rms_px),
            "method": "somacap wand bundle adjustment",
            "datum": "first camera fixed, scale from the bar length",
            "world": self.world,
            "bar_length_m": float(self.length_m),
            "bar_rms_mm": self.bar_rms_mm,
            "rmse_px": [float(x) for x in self.bundle.rmse_px],
        }


class _WandImages:
    """``images(cam_index, frame)`` over a scene's ``wand/`` folders (field applied)."""

    def __init__(self, scene):
        self.scene = scene
        self.n_cameras = len(scene.cameras)
        self.n_frames = len(scene.wand_frames()[scene.cameras[0]])

    def __call__(self, c: int, f: int) -> np.ndarray:
        return self.scene.wand_image(c, f)


def z_up_world(cameras: list[Camera], xyz: np.ndarray) -> tuple[list[Camera], np.ndarray]:
    """Express cameras in a Z-up world built from the cameras and the wand volume.

    +Z: the mean of the cameras' up vectors (the −y camera axis in the world);
    +X: camera 1's x axis with its Z part removed; origin: the centroid of the wand
    targets ``xyz`` (any shape (..., 3), NaN ignored) moved along Z down to the lowest
    target.  Rigid: scale and relative geometry are unchanged.

    Returns the cameras and ``T`` (4, 4) with ``X_new = T @ [X_old, 1]``.
    """
    up = np.mean([-c.R[1] for c in cameras], axis=0)
    z = up / np.linalg.norm(up)
    x = cameras[0].R[0] - (cameras[0].R[0] @ z) * z
    if np.linalg.norm(x) < 1e-9:  # camera 1 looks straight down
        x = np.cross(z, [0.0, 1.0, 0.0]) if abs(z[1]) < 0.9 else np.cross(z, [1.0, 0, 0])
    x /= np.linalg.norm(x)
    Rw = np.stack([x, np.cross(z, x), z])  # rows: new axes in the old frame
    pts = np.asarray(xyz, dtype=float).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    c = pts.mean(axis=0) if len(pts) else np.zeros(3)
    h = pts @ z if len(pts) else np.zeros(1)
    origin = c + (h.min() - c @ z) * z
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = Rw, -Rw @ origin
    out = [
        Camera(
            cam.name, cam.size, cam.K.copy(), cam.dist.copy(), cam.R @ Rw.T, cam.t + cam.R @ origin
        )
        for cam in cameras
    ]
    return out, T


def calibrate_detections(
    uv: np.ndarray,
    sizes,
    names,
    length_m: float,
    free: tuple[str, ...] = DEFAULT_FREE,
    aspect: float = 1.0,
    source: str = "wand",
    detections: WandDetections | None = None,
    progress: Progress | None = None,
    z_up: bool = False,
) -> CalibrationReport:
    """Calibrate from target points ``uv`` (F, C, 2, 2) (NaN where not measured).

    ``z_up``: express the result in the Z-up world of :func:`z_up_world` (the
    adjustment itself keeps camera 1 fixed as its datum).
    """
    both = np.all(np.isfinite(uv), axis=(2, 3))
    if not np.any(both.sum(axis=1) >= 2):
        raise InputError(f"{source}: no frame shows both wand targets in two or more cameras")
    if progress is not None:
        progress.update(0.7, 1.0, "initial orientation")
    _, init = search_focal(uv, sizes, length_m, names=names, aspect=aspect)
    if progress is not None:
        progress.update(0.8, 1.0, "bundle adjustment")
    res = adjust_wand(init.cameras, init.uv, init.xyz, length_m, free=free)
    ok_uv = np.where(res.outliers[..., None], np.nan, res.uv)
    pts = ok_uv.transpose(0, 2, 1, 3).reshape(-1, len(names), 2)
    tri = triangulate(res.cameras, pts)
    xyz = np.where(tri.ok[:, None], tri.xyz, np.nan).reshape(-1, 2, 3)
    bar = np.linalg.norm(xyz[:, 0] - xyz[:, 1], axis=1) - length_m
    if progress is not None:
        progress.update(1.0, 1.0, "calibrated")
    det = detections if detections is not None else WandDetections(uv, np.where(both, 2, 0))
    cams, world, T = res.cameras, "camera 1 frame (the adjustment datum)", np.eye(4)
    if z_up:
        cams, T = z_up_world(res.cameras, res.xyz)
        world = (
            "Z up = mean camera up vector; origin = wand-volume centroid dropped to the "
            "lowest wand position; X = camera 1's x axis made horizontal"
        )
    return CalibrationReport(
        cameras=cams,
        bundle=res,
        detections=det,
        length_m=length_m,
        bar_residual_m=bar,
        uv=res.uv,
        world=world,
        world_from_datum=T,
    )


def calibrate_scene(
    scene, free: tuple[str, ...] | None = None, progress: Progress | None = None, z_up: bool = False
) -> CalibrationReport:
    """Calibrate a loaded :class:`core.scene.Scene` from its ``wand/`` sequence.

    Single-field scenes (``field`` odd/even) start from pixel aspect 2 and adjust it.
    """
    if not scene.has_wand:
        raise InputError(f"{scene.root / 'wand'}: the scene has no wand sequence")
    length = scene.wand_length()
    images = _WandImages(scene)
    sub = None
    if progress is not None:
        sub = Progress(callback=lambda frac, msg: progress.update(0.7 * frac, 1.0, msg))
        sub.cancel_event = progress.cancel_event
    det = detect_sequence(images, progress=sub)
    aspect = 1.0 if scene.field == "none" else 2.0
    if free is None:
        free = DEFAULT_FREE + (("aspect",) if aspect != 1.0 else ())
    sizes = [scene.camera_size(c) for c in scene.cameras]
    return calibrate_detections(
        det.uv,
        sizes,
        list(scene.cameras),
        length,
        free=free,
        aspect=aspect,
        source=str(scene.root / "wand"),
        detections=det,
        progress=progress,
        z_up=z_up,
    )


def compare_to_reference(cameras: list[Camera], reference: list[Camera], source: str = "") -> dict:
    """Errors of calibrated cameras against a reference after a similarity alignment.

    The calibrated world is camera 1's frame with scale from L; the reference (e.g. the
    truth) has its own world, so the camera centres are aligned by the best similarity
    (Umeyama) before they are compared.  Returns centre errors (m), relative focal
    errors, aspect and the similarity scale.
    """
    if len(cameras) != len(reference):
        raise InputError(
            f"{source}: has {len(reference)} cameras but the calibration has "
            f"{len(cameras)}: the camera counts must match"
        )
    ref = {c.name: c for c in reference}
    missing = [c.name for c in cameras if c.name not in ref]
    if missing:
        raise InputError(f"{source}: has no camera named {missing[0]}")
    pairs = [(c, ref[c.name]) for c in cameras]
    a = np.array([c.center for c, _ in pairs])
    b = np.array([r.center for _, r in pairs])
    s, R, t = similarity(a, b)
    err = np.linalg.norm(s * a @ R.T + t - b, axis=1)
    return {
        "centre_error_m": err,
        "scale": s,
        "focal_error": np.array([c.K[0, 0] / r.K[0, 0] - 1 for c, r in pairs]),
        "aspect": np.array([c.aspect for c, _ in pairs]),
    }


def similarity(src: np.ndarray, dst: np.ndarray):
    """Umeyama similarity ``dst ≈ s R src + t`` of (N, 3) point sets: (s, R (3, 3), t (3,))."""
    mu_s, mu_d = src.mean(0), dst.mean(0)
    a, b = src - mu_s, dst - mu_d
    U, S, Vt = np.linalg.svd(b.T @ a / len(src))
    D = np.eye(3)
    D[2, 2] = np.sign(np.linalg.det(U @ Vt))
    R = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / (a**2).sum(axis=1).mean())
    return s, R, mu_d - s * R @ mu_s
