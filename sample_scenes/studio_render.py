"""Rendering helpers of the capture studio (bpy): looks, render settings, cameras.

Blender cameras equal to :class:`core.camera.Camera` (square pixels, centred principal
point), transparent-film renders composed over a background in numpy (so the mask is
the alpha channel by construction), and interlaced fields.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from core.camera import Camera
from core.errors import InputError

from .texture import box_uvs, surface_texture


def bpy_module():
    """The bpy module, or one InputError saying the studio needs it."""
    try:
        import bpy
    except ImportError as exc:  # pragma: no cover - the environment ships bpy
        raise InputError("the studio needs the bpy module (Blender as a Python module)") from exc
    return bpy


def apply_look(meshes, look: str, seed: int, engine: str) -> None:
    bpy = bpy_module()
    tex = surface_texture(look, 1024, seed)
    img = bpy.data.images.new(f"somacap_{look}", 1024, 1024, alpha=True)
    rgba = np.concatenate([tex[::-1], np.ones(tex.shape[:2] + (1,), np.float32)], axis=-1)
    img.pixels.foreach_set(rgba.ravel())
    img.pack()
    mat = bpy.data.materials.new(f"somacap_{look}")
    nt = mat.node_tree
    bsdf = next(n for n in nt.nodes if n.type == "BSDF_PRINCIPLED")
    node = nt.nodes.new("ShaderNodeTexImage")
    node.image = img
    node.interpolation = "Linear"
    nt.links.new(node.outputs["Color"], bsdf.inputs["Base Color"])
    bsdf.inputs["Roughness"].default_value = 0.9
    nt.nodes.active = node
    for o in meshes:
        me = o.data
        M = np.array(o.matrix_world)
        co = np.empty(len(me.vertices) * 3)
        me.vertices.foreach_get("co", co)
        co = co.reshape(-1, 3) @ M[:3, :3].T + M[:3, 3]
        lv = np.empty(len(me.loops), np.int64)
        me.loops.foreach_get("vertex_index", lv)
        nrm = np.empty(len(me.polygons) * 3)
        me.polygons.foreach_get("normal", nrm)
        loop_face = np.repeat(np.arange(len(me.polygons)), [p.loop_total for p in me.polygons])
        uv = box_uvs(co[lv], nrm.reshape(-1, 3) @ M[:3, :3].T, loop_face)
        layer = me.uv_layers.new(name="somacap_box")
        layer.data.foreach_set("uv", uv.ravel())
        me.uv_layers.active = layer
        me.materials.clear()
        me.materials.append(mat)


def setup_render(options) -> None:
    """Resolution, transparent film, 8-bit PNG and the engine of ``options`` (studio Options)."""
    bpy = bpy_module()
    sc = bpy.context.scene
    w, h = options.size
    r = sc.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = w, h, 100
    r.pixel_aspect_x = r.pixel_aspect_y = 1.0
    r.film_transparent = True
    r.image_settings.file_format = "PNG"
    r.image_settings.color_mode = "RGBA"
    r.image_settings.color_depth = "8"
    sc.view_settings.view_transform = "Standard"
    sc.view_settings.look = "None"
    if options.engine == "workbench":
        r.engine = "BLENDER_WORKBENCH"
        sh = sc.display.shading
        sh.light = "FLAT"
        sh.color_type = "TEXTURE"
        sc.display.render_aa = "8"
    elif options.engine == "cycles":
        r.engine = "CYCLES"
        sc.cycles.device = "CPU"
        sc.cycles.samples = int(options.samples)
        sc.cycles.use_denoising = False
        sc.cycles.seed = int(options.seed)
        world = sc.world or bpy.data.worlds.new("somacap")
        sc.world = world
        bg = next(n for n in world.node_tree.nodes if n.type == "BACKGROUND")
        bg.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
        bg.inputs["Strength"].default_value = 1.0
    else:
        raise InputError(f"engine must be workbench or cycles, got '{options.engine}'")


def blender_camera(cam: Camera):
    """A Blender camera object equal to ``cam`` (square pixels, centred principal point)."""
    bpy = bpy_module()
    import mathutils

    data = bpy.data.cameras.new(cam.name)
    data.sensor_fit = "HORIZONTAL"
    data.sensor_width = 36.0
    data.lens = float(cam.K[0, 0]) * 36.0 / cam.size[0]
    data.clip_start, data.clip_end = 0.05, 200.0
    obj = bpy.data.objects.new(cam.name, data)
    bpy.context.scene.collection.objects.link(obj)
    M = np.eye(4)
    M[:3, :3] = cam.R.T @ np.diag([1.0, -1.0, -1.0])  # OpenCV -> Blender camera axes
    M[:3, 3] = cam.center
    obj.matrix_world = mathutils.Matrix(M.tolist())
    return obj


def render_rgba(cam_obj, tmp: Path) -> np.ndarray:
    """Render the scene through ``cam_obj``; RGBA float32 (H, W, 4) in [0, 1]."""
    bpy = bpy_module()
    sc = bpy.context.scene
    sc.camera = cam_obj
    path = tmp / "render.png"
    sc.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    rgba = cv2.cvtColor(img, cv2.COLOR_BGRA2RGBA).astype(np.float32) / 255.0
    return rgba


def compose(
    rgba: np.ndarray, background: np.ndarray, noise: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Straight-alpha render (as PNG stores it) over a background + Gaussian noise.

    ``noise`` is the standard deviation in grey levels.  Returns the 8-bit RGB image
    (H, W, 3) and the mask ``alpha >= 0.5`` (H, W).
    """
    a = rgba[..., 3:]
    img = (rgba[..., :3] * a + background * (1.0 - a)) * 255.0
    if noise > 0:
        img = img + rng.normal(0.0, noise, img.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8), rgba[..., 3] >= 0.5


def interlace(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Interlaced frame (H, W, ...): rows 0, 2, ... of ``first``, the rest of ``second``."""
    out = second.copy()
    out[0::2] = first[0::2]
    return out


def field_camera(cam: Camera) -> Camera:
    """The odd-field (rows 0, 2, ...) camera of a full-frame camera."""
    K = cam.K.copy()
    K[1, 1] /= 2.0
    K[1, 2] /= 2.0
    w, h = cam.size
    return Camera(cam.name, (w, (h + 1) // 2), K, cam.dist, cam.R, cam.t)


def write_png(path: Path, rgb: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 9])
