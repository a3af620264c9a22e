"""The calibration wand of the capture studio: random bar positions, rendered blobs."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from core import toml_write
from core.camera import Camera
from core.errors import InputError

from .studio_render import bpy_module, compose, render_rgba, write_png


def wand_positions(
    cams: list[Camera],
    lo: np.ndarray,
    hi: np.ndarray,
    n: int,
    length: float,
    radius_px: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """Random bar positions ``(n, 2, 3)`` (target world positions, metres).

    Centres uniform in the box ``lo..hi``, directions uniform on the sphere; kept only
    when both targets fall inside every image (with a margin) and their blobs do not
    touch in any view.
    """
    out = []
    tries = 0
    while len(out) < n:
        tries += 1
        if tries > 2000:
            raise InputError("cannot place the wand inside every camera; widen the rig")
        m = 4 * n
        c = lo + (hi - lo) * rng.random((m, 3))
        d = rng.normal(size=(m, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        xyz = np.stack([c - d * length / 2, c + d * length / 2], axis=1)
        ok = np.ones(m, bool)
        for cam in cams:
            uv = cam.project(xyz)
            w, h = cam.size
            pad = radius_px + 2
            ok &= np.all(
                (uv[..., 0] > pad)
                & (uv[..., 0] < w - 1 - pad)
                & (uv[..., 1] > pad)
                & (uv[..., 1] < h - 1 - pad),
                axis=1,
            )
            ok &= np.linalg.norm(uv[:, 0] - uv[:, 1], axis=1) > 4 * radius_px + 2
        out.extend(xyz[ok])
    return np.array(out[:n])


def render_wand(
    cams, cam_objs, hide, options, lo, hi, out: Path, tmp: Path, rng, progress=None
) -> tuple[int, float]:
    """Render the wand at ``options.wand_positions`` random positions inside ``lo..hi``.

    Hides ``hide`` (the character) meanwhile; writes ``wand/<camera>/NNNNNN.png``,
    ``wand.toml`` and ``wand_truth.npz`` under ``out``.  Returns (renders, seconds).
    """
    bpy = bpy_module()
    sc = bpy.context.scene
    for o in hide:
        o.hide_render = True
    dist = np.mean([np.linalg.norm(c.center - (lo + hi) / 2) for c in cams])
    f = np.mean([c.K[0, 0] for c in cams])
    radius_px = float(np.clip(options.size[1] / 150, 1.5, 3.0))
    radius = radius_px * dist / f
    xyz = wand_positions(cams, lo, hi, options.wand_positions, options.wand_length, radius_px, rng)
    mat = bpy.data.materials.new("somacap_wand")
    nt = mat.node_tree
    for n in list(nt.nodes):
        if n.type != "OUTPUT_MATERIAL":
            nt.nodes.remove(n)
    em = nt.nodes.new("ShaderNodeEmission")
    em.inputs["Strength"].default_value = 1.0
    nt.links.new(em.outputs["Emission"], nt.nodes["Material Output"].inputs["Surface"])
    targets = []
    for k in range(2):
        me = bpy.data.meshes.new(f"wand_target_{k}")
        import bmesh

        bm = bmesh.new()
        bmesh.ops.create_uvsphere(bm, u_segments=24, v_segments=12, radius=radius)
        bm.to_mesh(me)
        bm.free()
        for p in me.polygons:
            p.use_smooth = True
        me.materials.append(mat)
        obj = bpy.data.objects.new(f"wand_target_{k}", me)
        obj.color = (1.0, 1.0, 1.0, 1.0)
        sc.collection.objects.link(obj)
        targets.append(obj)
    if options.engine == "workbench":
        sc.display.shading.color_type = "OBJECT"
    black = np.zeros((options.size[1], options.size[0], 3), np.float32)
    t0, renders = time.perf_counter(), 0
    for i, pair in enumerate(xyz):
        for k in range(2):
            targets[k].location = pair[k].tolist()
        for cam, obj in zip(cams, cam_objs, strict=True):
            rgb, _ = compose(render_rgba(obj, tmp), black, options.noise, rng)
            write_png(out / "wand" / cam.name / f"{i:06d}.png", rgb)
            renders += 1
        if progress is not None:
            progress.update(i + 1, len(xyz), f"rendered wand position {i + 1}/{len(xyz)}")
    for o in targets:
        o.hide_render = True
    if options.engine == "workbench":
        sc.display.shading.color_type = "TEXTURE"
    for o in hide:
        o.hide_render = False
    toml_write.dump(
        {
            "length_m": float(options.wand_length),
            "positions": int(len(xyz)),
            "target_radius_m": float(radius),
            "truth": "wand_truth.npz",
        },
        out / "wand.toml",
    )
    np.savez_compressed(
        out / "wand_truth.npz",
        xyz=xyz.astype(np.float64),
        doc=np.array("xyz (N, 2, 3): world positions of the two targets per wand position, metres"),
    )
    return renders, time.perf_counter() - t0
