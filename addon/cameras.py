"""Blender cameras from a calibration, and back.

OpenCV interior orientation ``K`` (pixels) maps to a Blender camera with a horizontal
sensor fit: ``lens = fx * sensor_width / W`` (mm), the principal point to
``shift_x, shift_y`` and the pixel aspect ``fx / fy`` to the scene's
``render.pixel_aspect_y / pixel_aspect_x``.  Pixel convention of the project: (0, 0) is
the centre of the top-left pixel, so the image centre is ``((W - 1) / 2, (H - 1) / 2)``.

Exterior orientation: OpenCV's camera looks down +z with y down, Blender's down -z with
y up, so the Blender world->camera rotation is ``diag(1, -1, -1) @ R`` and the object's
``matrix_world`` is ``[R_bl.T | C]`` with the projection centre ``C = -R.T @ t``.

Render resolution and pixel aspect are per scene in Blender; each camera object keeps
its own size, aspect source and distortion as custom properties (``somacap_size``,
``somacap_dist``) so that a calibration survives the round trip; the scene takes the
first camera's resolution.  Distortion is not modelled by Blender's camera (a lens
distortion node would be needed) and is carried only as data.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from . import _core

#: OpenCV camera axes -> Blender camera axes (x same, y and z flipped).
CV_TO_BLENDER = np.diag([1.0, -1.0, -1.0])
SENSOR_WIDTH_MM = 36.0


def blender_intrinsics(
    K: np.ndarray, size: tuple[int, int], sensor_width: float = SENSOR_WIDTH_MM
) -> dict:
    """OpenCV ``K`` (3, 3) px and ``size`` (W, H) -> Blender camera/render settings.

    Returns a dict with ``lens`` and ``sensor_width`` (mm), ``sensor_fit``
    (``"HORIZONTAL"``), ``shift_x``, ``shift_y`` (fractions of the image width) and
    ``pixel_aspect_x``, ``pixel_aspect_y`` (their ratio ``y / x`` equals ``fx / fy``;
    the smaller one is 1).  Skew (``K[0, 1]``) has no Blender counterpart and is ignored.
    """
    K = np.asarray(K, dtype=float)
    W, H = int(size[0]), int(size[1])
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    ycor = fx / fy  # Blender's ycor = pixel_aspect_y / pixel_aspect_x
    pax, pay = (1.0, ycor) if ycor >= 1.0 else (1.0 / ycor, 1.0)
    return {
        "lens": fx * sensor_width / W,
        "sensor_width": sensor_width,
        "sensor_fit": "HORIZONTAL",
        "shift_x": ((W - 1) / 2.0 - cx) / W,
        "shift_y": (cy - (H - 1) / 2.0) * ycor / W,
        "pixel_aspect_x": pax,
        "pixel_aspect_y": pay,
    }


def intrinsics_from_blender(
    lens: float,
    sensor_width: float,
    sensor_height: float,
    sensor_fit: str,
    shift_x: float,
    shift_y: float,
    size: tuple[int, int],
    pixel_aspect_x: float = 1.0,
    pixel_aspect_y: float = 1.0,
) -> np.ndarray:
    """Blender camera settings -> OpenCV ``K`` (3, 3) in pixels.

    Follows Blender's view-plane computation (``BKE_camera_params_compute_viewplane``):
    the sensor spans ``W`` pixels (horizontal fit) or ``ycor * H`` (vertical fit;
    ``AUTO`` picks the larger), shifts are in units of that span.
    """
    W, H = int(size[0]), int(size[1])
    ycor = pixel_aspect_y / pixel_aspect_x
    fit = sensor_fit
    if fit == "AUTO":
        fit = "HORIZONTAL" if W >= ycor * H else "VERTICAL"
        sensor = sensor_width
    else:
        sensor = sensor_width if fit == "HORIZONTAL" else sensor_height
    viewfac = W if fit == "HORIZONTAL" else ycor * H
    fx = lens * viewfac / sensor
    fy = fx / ycor
    cx = (W - 1) / 2.0 - shift_x * viewfac
    cy = (H - 1) / 2.0 + shift_y * viewfac / ycor
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def blender_matrix_world(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """OpenCV world->camera ``R`` (3, 3), ``t`` (3,) m -> Blender ``matrix_world`` (4, 4)."""
    R = np.asarray(R, dtype=float)
    t = np.asarray(t, dtype=float).reshape(3)
    M = np.eye(4)
    M[:3, :3] = (CV_TO_BLENDER @ R).T
    M[:3, 3] = -R.T @ t
    return M


def extrinsics_from_matrix_world(M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Blender camera ``matrix_world`` (4, 4) -> OpenCV ``R`` (3, 3), ``t`` (3,) m.

    Object scale is divided out (cameras ignore it); the rotation is re-orthonormalised.
    """
    M = np.asarray(M, dtype=float)
    A = M[:3, :3] / np.linalg.norm(M[:3, :3], axis=0, keepdims=True)
    U, _, Vt = np.linalg.svd(A)
    R_bl = (U @ Vt).T  # world -> Blender camera
    R = CV_TO_BLENDER @ R_bl
    t = -R @ M[:3, 3]
    return R, t


# -- bpy side -------------------------------------------------------------------------


def create_cameras(cameras, *, scene=None, collection=None, image_dirs: dict | None = None):
    """Create one Blender camera object per calibrated camera.

    Parameters
    ----------
    cameras : list of core.camera.Camera
    scene : bpy.types.Scene, optional
        Gets the first camera's resolution and pixel aspect (default: context scene).
    collection : bpy.types.Collection, optional
        Where the objects go (default: a new ``"Somacap cameras"`` collection).
    image_dirs : dict, optional
        Camera name -> folder of frames (``000000.png`` …) shown as the camera's
        background image sequence.

    Returns
    -------
    list of bpy.types.Object
    """
    import bpy
    from mathutils import Matrix

    scene = scene or bpy.context.scene
    if collection is None:
        collection = bpy.data.collections.new("Somacap cameras")
        scene.collection.children.link(collection)
    objects = []
    for i, cam in enumerate(cameras):
        p = blender_intrinsics(cam.K, cam.size)
        data = bpy.data.cameras.new(cam.name)
        data.type = "PERSP"
        data.lens_unit = "MILLIMETERS"
        data.sensor_fit = p["sensor_fit"]
        data.sensor_width = p["sensor_width"]
        data.sensor_height = p["sensor_width"] * cam.size[1] / cam.size[0]
        data.lens = p["lens"]
        data.shift_x, data.shift_y = p["shift_x"], p["shift_y"]
        obj = bpy.data.objects.new(cam.name, data)
        obj.matrix_world = Matrix(blender_matrix_world(cam.R, cam.t).tolist())
        obj["somacap_camera"] = cam.name
        obj["somacap_size"] = [int(cam.size[0]), int(cam.size[1])]
        obj["somacap_pixel_aspect"] = [p["pixel_aspect_x"], p["pixel_aspect_y"]]
        obj["somacap_dist"] = [float(d) for d in cam.dist]
        collection.objects.link(obj)
        if i == 0:
            _apply_render_settings(scene, obj)
            scene.camera = obj
        folder = (image_dirs or {}).get(cam.name)
        if folder is not None:
            _background_sequence(data, Path(folder))
        objects.append(obj)
    return objects


def _apply_render_settings(scene, obj) -> None:
    W, H = obj["somacap_size"]
    pax, pay = obj["somacap_pixel_aspect"]
    scene.render.resolution_x, scene.render.resolution_y = int(W), int(H)
    scene.render.resolution_percentage = 100
    scene.render.pixel_aspect_x, scene.render.pixel_aspect_y = float(pax), float(pay)


def _background_sequence(cam_data, folder: Path) -> None:
    import bpy

    frames = sorted(folder.glob("*.png")) + sorted(folder.glob("*.jpg"))
    if not frames:
        return
    img = bpy.data.images.load(str(frames[0]), check_existing=True)
    img.source = "SEQUENCE"
    bg = cam_data.background_images.new()
    bg.image = img
    bg.image_user.frame_duration = len(frames)
    bg.image_user.frame_start = 1
    bg.alpha = 0.6
    cam_data.show_background_images = True


def camera_from_object(obj, scene=None):
    """A Blender camera object -> ``core.camera.Camera`` (OpenCV conventions).

    Size and pixel aspect come from the object's ``somacap_*`` properties when present
    (cameras made by :func:`create_cameras`), else from the scene's render settings.
    """
    import bpy

    scene = scene or bpy.context.scene
    if obj.type != "CAMERA":
        raise _core.errors.InputError(f"object '{obj.name}' is not a camera")
    if "somacap_size" in obj:
        W, H = (int(v) for v in obj["somacap_size"])
        pax, pay = (float(v) for v in obj["somacap_pixel_aspect"])
    else:
        r = scene.render
        W = int(r.resolution_x * r.resolution_percentage / 100)
        H = int(r.resolution_y * r.resolution_percentage / 100)
        pax, pay = r.pixel_aspect_x, r.pixel_aspect_y
    d = obj.data
    K = intrinsics_from_blender(
        d.lens,
        d.sensor_width,
        d.sensor_height,
        d.sensor_fit,
        d.shift_x,
        d.shift_y,
        (W, H),
        pax,
        pay,
    )
    R, t = extrinsics_from_matrix_world(np.array(obj.matrix_world))
    dist = np.asarray(obj.get("somacap_dist", [0.0] * 5), dtype=float)
    name = str(obj.get("somacap_camera", obj.name))
    return _core.camera.Camera(name, (W, H), K, dist, R, t)
