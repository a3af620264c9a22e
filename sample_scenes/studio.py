"""The synthetic capture studio: a BVH clip played by a skinned character, rendered.

Run headless with the bpy module::

    python -m sample_scenes.studio --out sample_scenes/walk_line3

or from Python: :func:`render_scene`.  Writes a scene folder as SPEC.md describes
(``scene.toml``, ``calibration.toml``, ``images/``, ``wand/`` + ``wand.toml`` +
``wand_truth.npz``, ``clicks.json``, ``truth.npz``), see :mod:`core.scene`.

Rendering: the character is rendered on a transparent film; the alpha channel is the
foreground mask (``alpha >= 0.5``) and the image is composed over a static background
(plain grey or a noise texture) in numpy, so masks agree with the images by
construction.  Interlaced cameras render every frame twice, half a frame apart: the odd
field (rows 0, 2, ...) at ``t``, the even field at ``t + 1/(2 fps)``; ``scene.toml``
then says ``field = "odd"`` and ``calibration.toml`` and the truth masks describe the
odd-field image (height ``(h + 1) // 2``, ``fy`` and ``cy`` halved).

Truth joints (:data:`JOINT_BONES`) are bone heads/tails of the posed character.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from core import toml_write
from core.calibration_io import write_calibration
from core.errors import InputError
from core.landmarks import CLICK_JOINTS, JOINTS
from core.progress import Progress

from .bvh import CMU_SCALE, read_bvh
from .retarget import Rig, retarget
from .rigs import RIGS, frame_cameras
from .studio_render import (
    apply_look,
    blender_camera,
    bpy_module,
    compose,
    field_camera,
    interlace,
    render_rgba,
    setup_render,
    write_png,
)
from .studio_wand import render_wand
from .texture import LOOKS, background_image

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
DEFAULT_BVH = SHARED / "mocap" / "02_01.bvh"
DEFAULT_CHARACTER = SHARED / "characters" / "makehuman_cmu_mb.blend"

#: Truth joint -> (character bone, "head" | "tail").
JOINT_BONES = {
    "pelvis": ("Hips", "head"),
    "spine": ("Spine", "head"),
    "chest": ("Spine1", "head"),
    "neck": ("Neck", "head"),
    "head": ("Head", "head"),
    "head_top": ("Head", "tail"),
    "l_clavicle": ("LeftShoulder", "head"),
    "l_shoulder": ("LeftArm", "head"),
    "l_elbow": ("LeftForeArm", "head"),
    "l_wrist": ("LeftHand", "head"),
    "l_hand": ("LeftFingerBase", "tail"),
    "r_clavicle": ("RightShoulder", "head"),
    "r_shoulder": ("RightArm", "head"),
    "r_elbow": ("RightForeArm", "head"),
    "r_wrist": ("RightHand", "head"),
    "r_hand": ("RightFingerBase", "tail"),
    "l_hip": ("LeftUpLeg", "head"),
    "l_knee": ("LeftLeg", "head"),
    "l_ankle": ("LeftFoot", "head"),
    "l_toe": ("LeftToeBase", "head"),
    "r_hip": ("RightUpLeg", "head"),
    "r_knee": ("RightLeg", "head"),
    "r_ankle": ("RightFoot", "head"),
    "r_toe": ("RightToeBase", "head"),
}

ATTRIBUTION = (
    "Motion: CMU Graphics Lab Motion Capture Database, mocap.cs.cmu.edu "
    "(created with funding from NSF EIA-0196217). Character: MakeHuman / MPFB2 "
    "base mesh, CC0 1.0."
)


@dataclass
class Options:
    """Every studio setting (the command-line flags, same names)."""

    bvh: str = str(DEFAULT_BVH)
    start: int = 0
    frames: int = 50
    fps: float = 25.0
    character: str = str(DEFAULT_CHARACTER)
    rig: str = "line3"
    size: tuple = (512, 384)
    look: str = "sweater"
    background: str = "plain"
    interlace: bool = False
    noise: float = 0.0
    click_noise: float = 0.0
    wand_positions: int = 200
    wand_length: float = 0.5
    wand_only: bool = False
    engine: str = "workbench"
    samples: int = 16
    truth_vertices: str = "all"
    seed: int = 0
    name: str = ""


# --------------------------------------------------------------------------- bpy helpers
def load_character(path: Path):
    """Open a .blend or import a .glb; return ``(armature_object, [skinned mesh objects])``."""
    bpy = bpy_module()
    if not path.is_file():
        raise InputError(f"{path}: character file not found")
    suffix = path.suffix.lower()
    try:
        if suffix == ".blend":
            bpy.ops.wm.open_mainfile(filepath=str(path))
        elif suffix in (".glb", ".gltf"):
            bpy.ops.wm.read_factory_settings(use_empty=True)
            bpy.ops.import_scene.gltf(filepath=str(path))
        else:
            raise InputError(f"{path}: character must be a .blend or .glb file")
    except RuntimeError as exc:
        raise InputError(f"{path}: cannot be loaded as a character ({exc})") from exc
    arms = [o for o in bpy.context.scene.objects if o.type == "ARMATURE"]
    if not arms:
        raise InputError(f"{path}: holds no armature to drive")
    arm = arms[0]
    meshes = [
        o
        for o in bpy.context.scene.objects
        if o.type == "MESH" and any(m.type == "ARMATURE" and m.object == arm for m in o.modifiers)
    ]
    if not meshes:
        raise InputError(f"{path}: holds no mesh skinned to the armature '{arm.name}'")
    for o in bpy.context.scene.objects:
        if o.type in ("CAMERA", "LIGHT") or (o.type == "MESH" and o not in meshes):
            o.hide_render = True
    return arm, meshes


def character_rig(arm) -> Rig:
    bones = list(arm.data.bones)
    names = [b.name for b in bones]
    parents = np.array([names.index(b.parent.name) if b.parent else -1 for b in bones])
    return Rig(
        names,
        parents,
        np.array([np.array(b.matrix_local) for b in bones]),
        np.array([np.array(b.tail_local) for b in bones]),
    )


def _set_pose(arm, names, basis: np.ndarray) -> None:
    import mathutils

    for i, n in enumerate(names):
        arm.pose.bones[n].matrix_basis = mathutils.Matrix(basis[i].tolist())


def _evaluated_vertices(meshes, depsgraph) -> np.ndarray:
    out = []
    for o in meshes:
        ev = o.evaluated_get(depsgraph)
        me = ev.to_mesh()
        co = np.empty(len(me.vertices) * 3, np.float32)
        me.vertices.foreach_get("co", co)
        M = np.array(ev.matrix_world)
        out.append(co.reshape(-1, 3) @ M[:3, :3].T.astype(np.float32) + M[:3, 3])
        ev.to_mesh_clear()
    return np.concatenate(out).astype(np.float32)


def _faces(meshes) -> np.ndarray:
    out, base = [], 0
    for o in meshes:
        me = o.data
        me.calc_loop_triangles()
        tri = np.empty(len(me.loop_triangles) * 3, np.int64)
        me.loop_triangles.foreach_get("vertices", tri)
        out.append(tri.reshape(-1, 3) + base)
        base += len(me.vertices)
    return np.concatenate(out).astype(np.int32)


# --------------------------------------------------------------------------- main entry
def render_scene(out_dir: str | Path, progress=None, **options) -> Path:
    """Render a scene folder into ``out_dir`` in this process (needs bpy); return the path.

    Keyword options are the fields of :class:`Options` (e.g. ``rig="ring4"``,
    ``size=(64, 48)``, ``frames=3``).  Raises :class:`~core.errors.InputError` for bad input.
    A ``.blend`` character is opened as the current file (replacing what bpy had open);
    run it in a subprocess (``python -m sample_scenes.studio``) to keep a session intact.
    ``progress`` (a :class:`core.progress.Progress`) is updated once per rendered frame.
    """
    opt = Options(**options)
    opt.size = (int(opt.size[0]), int(opt.size[1]))
    out = Path(out_dir)
    if opt.look not in LOOKS:
        raise InputError(f"look must be one of {LOOKS}, got '{opt.look}'")
    if opt.rig not in RIGS:
        raise InputError(f"rig must be one of {RIGS}, got '{opt.rig}'")
    if opt.background not in ("plain", "textured"):
        raise InputError(f"background must be plain or textured, got '{opt.background}'")
    if opt.frames < 1 or opt.fps <= 0 or min(opt.size) < 8:
        raise InputError("frames must be >= 1, fps > 0 and the size at least 8x8 pixels")
    bvh = read_bvh(opt.bvh)
    char_path = Path(opt.character)
    if not char_path.is_file():
        raise InputError(f"{char_path}: character file not found")
    t_start = opt.start * bvh.frame_time
    times = t_start + np.arange(opt.frames) / opt.fps
    t_last = times[-1] + (0.5 / opt.fps if opt.interlace else 0.0)
    if opt.start < 0 or t_last > (bvh.n_frames - 1) * bvh.frame_time + 1e-9:
        raise InputError(
            f"{bvh.path}: holds {bvh.n_frames} frames at "
            f"{1 / bvh.frame_time:g} fps, too few for frames {opt.start}.. "
            f"+{opt.frames} at {opt.fps:g} fps"
        )
    rng = np.random.default_rng(opt.seed)
    bpy = bpy_module()
    arm, meshes = load_character(char_path)
    rig = character_rig(arm)
    sample_times = times if not opt.interlace else np.concatenate([times, times + 0.5 / opt.fps])
    rt = retarget(rig, bvh, sample_times, CMU_SCALE, center_on=times)

    # Pose every sample time; collect the skinned vertices and bone matrices.
    depsgraph = bpy.context.evaluated_depsgraph_get()
    Wa = np.array(arm.matrix_world)
    verts, mats = [], []
    for k in range(len(sample_times)):
        _set_pose(arm, rig.names, rt.basis[k])
        bpy.context.view_layer.update()
        verts.append(_evaluated_vertices(meshes, depsgraph))
        mats.append(Wa @ np.array([np.array(arm.pose.bones[n].matrix) for n in rig.names]))
    verts, mats = np.array(verts), np.array(mats)
    tails = (
        mats
        @ np.concatenate(
            [
                np.zeros((len(rig.names), 1)),
                np.linalg.norm(rig.tails - rig.heads, axis=1)[:, None],
                np.zeros((len(rig.names), 1)),
                np.ones((len(rig.names), 1)),
            ],
            axis=1,
        )[..., None]
    )
    tails = tails[..., :3, 0]

    w, h = opt.size
    step = max(1, verts.shape[1] // 3000)
    cams = frame_cameras(
        opt.rig,
        verts[:, ::step].reshape(-1, 3).astype(float),
        mats[: len(times), rig.names.index("Hips"), :2, 3],
        opt.size,
    )
    cam_objs = [blender_camera(c) for c in cams]
    out_cams = [field_camera(c) for c in cams] if opt.interlace else cams

    out.mkdir(parents=True, exist_ok=True)
    setup_render(opt)
    apply_look(meshes, opt.look, opt.seed, opt.engine)
    lo = verts.reshape(-1, 3).min(axis=0).astype(float)
    hi = verts.reshape(-1, 3).max(axis=0).astype(float)
    timing = {}
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        renders, secs = render_wand(cams, cam_objs, meshes, opt, lo, hi, out, tmp, rng, progress)
        timing["wand_seconds_per_image"] = secs / max(renders, 1)
        if not opt.wand_only:
            masks, secs, renders = _render_frames(
                opt, arm, rig, rt, cams, cam_objs, out, tmp, rng, progress
            )
            timing["seconds_per_image"] = secs / max(renders, 1)
    write_calibration(
        out / "calibration.toml", out_cams, metadata={"source": "somacap studio (true cameras)"}
    )
    if not opt.wand_only:
        _write_truth(
            out,
            opt,
            rig,
            verts[: len(times)],
            mats[: len(times)],
            tails[: len(times)],
            _faces(meshes),
            masks,
            out_cams,
            times - t_start,
        )
        _write_clicks(out, opt, rig, mats[0], tails[0], out_cams, rng)
    _write_scene_toml(out, opt, cams, timing, rt)
    return out


def _render_frames(opt, arm, rig, rt, cams, cam_objs, out, tmp, rng, progress):
    w, h = opt.size
    n = opt.frames
    backgrounds = [
        background_image(opt.background, opt.size, opt.seed + 1 + c) for c in range(len(cams))
    ]
    fh = (h + 1) // 2 if opt.interlace else h
    masks = np.zeros((len(cams), n, fh, w), bool)
    t0, renders = time.perf_counter(), 0
    for i in range(n):
        passes = [i, n + i] if opt.interlace else [i]
        shots = []
        for k in passes:
            _set_pose(arm, rig.names, rt.basis[k])
            bpy_module().context.view_layer.update()
            shots.append([render_rgba(obj, tmp) for obj in cam_objs])
            renders += len(cam_objs)
        for c, cam in enumerate(cams):
            if opt.interlace:
                rgba = interlace(shots[0][c], shots[1][c])
            else:
                rgba = shots[0][c]
            rgb, mask = compose(rgba, backgrounds[c], opt.noise, rng)
            masks[c, i] = mask[0::2] if opt.interlace else mask
            write_png(out / "images" / cam.name / f"{i:06d}.png", rgb)
        if progress is not None:
            progress.update(i + 1, n, f"rendered frame {i + 1}/{n}")
    return masks, time.perf_counter() - t0, renders


def joint_positions(rig: Rig, mats: np.ndarray, tails: np.ndarray) -> np.ndarray:
    """Truth joints ``(F, J, 3)`` in :data:`core.landmarks.JOINTS` order."""
    idx = [rig.names.index(JOINT_BONES[j][0]) for j in JOINTS]
    use_tail = np.array([JOINT_BONES[j][1] == "tail" for j in JOINTS])
    heads = mats[:, idx][:, :, :3, 3]
    return np.where(use_tail[:, None], tails[:, idx, :], heads)


def _write_truth(out, opt, rig, verts, mats, tails, faces, masks, cams, frame_times):
    missing = sorted({b for b, _ in JOINT_BONES.values()} - set(rig.names))
    if missing:
        raise InputError(f"{opt.character}: the armature lacks the bones {missing}")
    joints = joint_positions(rig, mats, tails)
    rest_h = float(verts[0][:, 2].max() - verts[0][:, 2].min())
    data = dict(
        joint_names=np.array(JOINTS),
        joints_xyz=joints,
        bone_names=np.array(rig.names),
        bone_parents=rig.parents.astype(np.int32),
        bone_matrices=mats.astype(np.float64),
        faces=faces,
        masks=np.packbits(masks, axis=-1),
        camera_names=np.array([c.name for c in cams]),
        height_m=np.array(rest_h),
        frame_times=np.asarray(frame_times, float),
    )
    if opt.truth_vertices == "all":
        data["vertices"] = verts.astype(np.float32)
    np.savez_compressed(out / "truth.npz", **data)


def _write_clicks(out, opt, rig, mats0, tails0, cams, rng):
    xyz = joint_positions(rig, mats0[None], tails0[None])[0]
    joints = {}
    for name in CLICK_JOINTS:
        p = xyz[JOINTS.index(name)]
        joints[name] = {}
        for cam in cams:
            uv = cam.project(p) + rng.normal(0.0, opt.click_noise, 2) * (opt.click_noise > 0)
            joints[name][cam.name] = [round(float(uv[0]), 3), round(float(uv[1]), 3)]
    (out / "clicks.json").write_text(
        json.dumps({"frame": 0, "click_noise_px": opt.click_noise, "joints": joints}, indent=1)
        + "\n"
    )


def _write_scene_toml(out, opt, cams, timing, rt):
    meta = {
        "name": opt.name or out.name,
        "fps": float(opt.fps),
        "frames": 0 if opt.wand_only else int(opt.frames),
        "cameras": [c.name for c in cams],
        "size": [int(opt.size[0]), int(opt.size[1])],
        "field": "odd" if opt.interlace else "none",
        "source": {
            "bvh": Path(opt.bvh).name,
            "bvh_start_frame": int(opt.start),
            "character": Path(opt.character).name,
            "rig": opt.rig,
            "look": opt.look,
            "background": opt.background,
            "engine": opt.engine,
            "interlace": bool(opt.interlace),
            "noise_grey_levels": float(opt.noise),
            "click_noise_px": float(opt.click_noise),
            "seed": int(opt.seed),
            "retarget_scale": float(rt.scale),
            "retarget_offset_m": [float(v) for v in rt.offset],
            "attribution": ATTRIBUTION,
            **{k: round(v, 4) for k, v in timing.items()},
        },
    }
    if not opt.wand_only:
        meta["truth"] = {
            "file": "truth.npz",
            "joints": "bone heads/tails of the posed character, see sample_scenes.studio."
            "JOINT_BONES",
            "vertices": "all frames, float32"
            if opt.truth_vertices == "all"
            else "not stored (--truth-vertices none)",
            "masks": "alpha >= 0.5 of the render" + (", odd field" if opt.interlace else ""),
        }
    toml_write.dump(meta, out / "scene.toml")


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"size must look like 512x384, got '{text}'") from exc
    return w, h


def build_parser() -> argparse.ArgumentParser:
    d = Options()
    p = argparse.ArgumentParser(prog="studio", description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True, help="scene folder to write")
    p.add_argument("--bvh", default=d.bvh, help="BVH clip (CMU units)")
    p.add_argument("--start", type=int, default=d.start, help="first BVH frame")
    p.add_argument("--frames", type=int, default=d.frames, help="output frames")
    p.add_argument("--fps", type=float, default=d.fps, help="output frame rate")
    p.add_argument("--character", default=d.character, help=".blend or .glb character")
    p.add_argument("--rig", choices=RIGS, default=d.rig)
    p.add_argument("--size", type=_size, default=d.size, help="WxH pixels (512x384)")
    p.add_argument("--look", choices=LOOKS, default=d.look)
    p.add_argument("--background", choices=("plain", "textured"), default=d.background)
    p.add_argument("--interlace", action="store_true", help="odd/even fields half a frame apart")
    p.add_argument("--noise", type=float, default=d.noise, help="sensor noise sigma, grey levels")
    p.add_argument("--click-noise", type=float, default=d.click_noise, help="pixels")
    p.add_argument("--wand-positions", type=int, default=d.wand_positions)
    p.add_argument("--wand-length", type=float, default=d.wand_length, help="metres")
    p.add_argument("--wand-only", action="store_true", help="render only the wand sequence")
    p.add_argument("--engine", choices=("workbench", "cycles"), default=d.engine)
    p.add_argument("--samples", type=int, default=d.samples, help="Cycles samples")
    p.add_argument("--truth-vertices", choices=("all", "none"), default=d.truth_vertices)
    p.add_argument("--seed", type=int, default=d.seed)
    p.add_argument("--name", default="", help="scene name (default: the folder name)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    opts = {k: v for k, v in vars(args).items() if k != "out"}
    try:
        t0 = time.perf_counter()
        out = render_scene(args.out, progress=Progress(interval=5.0), **opts)
    except InputError as exc:
        print(f"studio: error: {exc}", file=sys.stderr)
        return 2
    print(f"studio: wrote {out} in {time.perf_counter() - t0:.1f} s")
    return 0


__all__ = ["Options", "render_scene", "main", "JOINT_BONES"]

if __name__ == "__main__":
    sys.exit(main())
