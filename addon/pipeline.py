"""The add-on's jobs as plain functions, shared by the panel's operators and the CLI.

Each function takes paths/objects, calls core, builds Blender data and returns what it
made; bad input raises :class:`core.errors.InputError` before the user's data changes.
"""

from __future__ import annotations

import tempfile
import threading
from pathlib import Path

import numpy as np

from . import _core, builders, cameras


def read_state(path):
    """Read and validate a fitted state (InputError naming the file on any problem)."""
    return _core.state.read_state(path)


#: The fit's cues (``core.fit_scene.CUES``), with one line each for help texts and the panel.
FIT_CUES = {
    "texture": "3-D surface points from the tracker (needs textured clothing)",
    "contours": "silhouette contours of each camera's foreground (no tracker; bare skin)",
    "both": "points and contours together, and each camera's texture flow in frames "
    "without points (most accurate; about 2.7x the fit's CPU time)",
}


def check_cues(cues: str) -> str:
    """``cues`` when it is one of :data:`FIT_CUES`, else InputError naming the choices."""
    if cues not in FIT_CUES:
        raise _core.errors.InputError(
            f"unknown fit cues {cues!r}: choose one of {', '.join(FIT_CUES)}"
        )
    return cues


#: The fit's options (keywords of :func:`run_fit`) and their defaults, which are core's:
#: any other value asks for a new fit (a scene's ``fit.json`` is not used).
FIT_OPTIONS = {
    "feet_from_points": False,
    "smooth_motion": False,
    "contour_starts": True,
    "late_shape": True,
    "flow_choice": True,
}


def asks_new_fit(**options) -> bool:
    """Whether any of the fit's options (:data:`FIT_OPTIONS`) differs from its default."""
    return any(bool(on) != FIT_OPTIONS[name] for name, on in options.items())


def sequence_settings(
    feet_from_points: bool = False,
    smooth_motion: bool = False,
    contour_starts: bool = True,
    late_shape: bool = True,
    flow_choice: bool = True,
):
    """core's ``SequenceSettings`` with the fit's options that differ from core's
    defaults set (the rest core's defaults), or None when none does: core's own default.

    ``feet_from_points`` sets ``foot_heading`` (:mod:`core.foot_heading`),
    ``smooth_motion`` sets ``smooth_motion`` (:mod:`core.motion_smoother`), both off by
    default; ``contour_starts`` sets ``contour_starts`` (on by default: a frame fitted
    from contours alone is fitted from three starts, :func:`core.fit.contour_starts`);
    ``late_shape=False`` sets ``late_shape_points`` to None (on by default: bones the
    shape frames hardly saw are shaped over the fitted take and the motion is fitted a
    second time, :mod:`core.fit_late_shape`; off, one pass, ``core fit --one-pass``).
    One pass also leaves out the shape over several frames that a take shaped by its
    silhouettes alone gets on a wide rig (``ContourSettings.shape_fit_frames``).
    ``flow_choice`` sets ``flow_choice`` (on by default: a take the silhouettes shape
    and that follows the texture flow is fitted a second time with LSM-refined flow
    corners and the fit the foregrounds explain better is kept, :mod:`core.fit_choice`;
    off, one fit with Lucas–Kanade's corners, ``core fit --one-flow``).
    """
    SequenceSettings = _core.load("fit").SequenceSettings
    default = SequenceSettings()
    asked = {
        "foot_heading": feet_from_points,
        "smooth_motion": smooth_motion,
        "contour_starts": contour_starts,
        "late_shape_points": default.late_shape_points if late_shape else None,
        "flow_choice": flow_choice,
    }
    fields = {name: v for name, v in asked.items() if v != getattr(default, name)}
    return SequenceSettings(**fields) if fields else None


def run_fit(
    scene_dir,
    out_json,
    progress=None,
    cues: str = "texture",
    clicks_xyz=None,
    feet_from_points: bool = False,
    smooth_motion: bool = False,
    contour_starts: bool = True,
    late_shape: bool = True,
    flow_choice: bool = True,
) -> Path:
    """Run core's whole pipeline on a scene folder and write ``fit.json``
    (:func:`core.fit_scene.fit_scene`; cancellable through ``progress``).

    ``cues`` chooses the observations of the fit (:data:`FIT_CUES`): ``"texture"``,
    ``"contours"`` or ``"both"``.  ``clicks_xyz`` (``{joint: (3,) world metres}``, e.g.
    :func:`moved_clicks`) replaces those joints' clicks for this fit only: each is
    clicked where it projects in the cameras that clicked it (``clicks.json`` is left
    as it is).  ``feet_from_points=True`` turns each foot about its shin at the clicked
    frame to the heading of the surface points under it
    (``SequenceSettings(foot_heading=True)``, :mod:`core.foot_heading`; off by default,
    and a no-op without points, i.e. with ``cues="contours"``).  ``smooth_motion=True``
    smooths the fitted motion over the take, each joint's path, then the angles solved
    to it (``SequenceSettings(smooth_motion=True)``, :mod:`core.motion_smoother`; off by
    default, as it spreads a sudden kick of one limb over the neighbouring frames).
    ``contour_starts=False`` fits a frame without texture points (contours alone) from
    the prediction only, not also from the previous frame's pose and its extrapolation
    (``SequenceSettings(contour_starts=False)``, ``core fit --prediction-start-only``;
    on by default: about 2x the fit time on a rig without points, but it keeps fast
    limbs, e.g. on the orthogonal rig).  ``late_shape=False`` fits the motion once: no
    late shape and no second pass (``core fit --one-pass``; on by default, about 2x the
    fit time where a bone qualifies, make demo's walk 12.9 → 11.1 mm).
    ``flow_choice=False`` fits a take that the silhouettes shape (no texture points at
    the clicked frame, e.g. the orthogonal rig) and that follows the texture flow once,
    with Lucas–Kanade's flow corners (``SequenceSettings(flow_choice=False)``, ``core fit
    --one-flow``; on by default: such a take is fitted a second time with LSM-refined
    flow corners and the fit the foregrounds explain better is kept,
    :mod:`core.fit_choice`, about twice the fit time there).  The options
    that differ from these defaults give one ``SequenceSettings`` with all of them set
    (:func:`sequence_settings`); none, core's default settings are used (no
    ``settings`` is passed).
    """
    scene_dir, out_json = Path(scene_dir), Path(out_json)
    check_cues(cues)
    sc = _core.scene.load_scene(scene_dir)
    if clicks_xyz:
        moved = _core.fit_init.clicks_at(sc.clicks(), sc.calibration(), clicks_xyz)
        sc.clicks = lambda: moved
    settings = sequence_settings(
        feet_from_points=feet_from_points,
        smooth_motion=smooth_motion,
        contour_starts=contour_starts,
        late_shape=late_shape,
        flow_choice=flow_choice,
    )
    kw = {} if settings is None else {"settings": settings}
    state = _core.load("fit_scene").fit_scene(sc, progress=progress, cues=cues, **kw)
    _core.state.write_state(out_json, state)
    return out_json


def state_for_scene(
    scene_dir,
    fit_path=None,
    progress=None,
    cues: str = "texture",
    refit: bool = False,
    clicks_xyz=None,
    feet_from_points: bool = False,
    smooth_motion: bool = False,
    contour_starts: bool = True,
    late_shape: bool = True,
    flow_choice: bool = True,
):
    """The fitted state of a scene: ``fit_path``, else ``SCENE/fit.json``, else fit now.

    A fit uses ``cues`` (:data:`FIT_CUES`); ``refit=True`` fits even when
    ``SCENE/fit.json`` exists (which is then neither used nor overwritten), and so do
    joints dragged in the viewport (``clicks_xyz``), ``feet_from_points=True`` (the
    feet turned to their points), ``smooth_motion=True`` (the motion smoothed over
    the take), ``contour_starts=False`` (frames from contours alone fitted from the
    prediction only), ``late_shape=False`` (one pass) and ``flow_choice=False`` (one
    fit with Lucas–Kanade's flow corners; all :func:`run_fit`).
    """
    scene_dir = Path(scene_dir)
    check_cues(cues)
    if fit_path:
        return read_state(fit_path)
    options = {
        "feet_from_points": feet_from_points,
        "smooth_motion": smooth_motion,
        "contour_starts": contour_starts,
        "late_shape": late_shape,
        "flow_choice": flow_choice,
    }
    fresh = refit or clicks_xyz or asks_new_fit(**options)
    if not fresh and (scene_dir / "fit.json").is_file():
        return read_state(scene_dir / "fit.json")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "fit.json"
        return read_state(
            run_fit(
                scene_dir,
                out,
                progress,
                cues=cues,
                clicks_xyz=clicks_xyz,
                **options,
            )
        )


def create_scene_cameras(scene_dir, calibration=None):
    """Blender cameras for a scene folder (or an explicit calibration file), with the
    camera's image sequence as background.  Returns the camera objects."""
    scene_dir = Path(scene_dir) if scene_dir else None
    if calibration:
        cams = _core.calibration_io.read_calibration(calibration)
    elif scene_dir is not None:
        cams = _core.calibration_io.read_calibration(scene_dir / "calibration.toml")
    else:
        raise _core.errors.InputError("choose a scene folder or a calibration file")
    image_dirs = {}
    if scene_dir is not None:
        image_dirs = {
            c.name: scene_dir / "images" / c.name
            for c in cams
            if (scene_dir / "images" / c.name).is_dir()
        }
    return cameras.create_cameras(cams, image_dirs=image_dirs)


def place_clicks(scene_dir):
    """Empties at the forward intersection of the scene's clicked key joints.

    Returns ``{joint: empty}``; the empties are named ``click_<joint>`` and can be
    moved in the viewport (read back with :func:`clicked_positions`).  Each is drawn as
    the 3σ ellipsoid of its intersection for clicks off by 1 px (at least 1 cm across):
    with cameras in a line it is long along their view, the depth the clicks fix worst
    and the fit keeps in every frame — the direction to check and drag it in a side
    view.  ``empty["somacap_sigma_mm"]`` holds its σ, smallest first, mm per pixel.
    """
    import bpy
    from mathutils import Matrix

    sc = _core.scene.load_scene(scene_dir, check_images=False)
    cams = sc.calibration()
    clicks = sc.clicks()
    joints = sorted(clicks["joints"])
    uv = np.full((len(joints), len(cams), 2), np.nan)
    for i, j in enumerate(joints):
        for c, cam in enumerate(cams):
            if cam.name in clicks["joints"][j]:
                uv[i, c] = clicks["joints"][j][cam.name]
    res = _core.intersect.triangulate(cams, uv, sigma_px=1.0)
    coll = bpy.data.collections.new("Somacap clicks")
    bpy.context.scene.collection.children.link(coll)
    out = {}
    for j, p, cov in zip(joints, res.xyz, res.cov, strict=True):
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(cov))):
            continue
        e = bpy.data.objects.new(f"click_{j}", None)
        e.empty_display_type = "SPHERE"
        e.empty_display_size = 1.0
        var, axes = np.linalg.eigh(cov)
        axes[:, 0] *= np.sign(np.linalg.det(axes))  # a rotation
        sigma = np.sqrt(np.clip(var, 0.0, None))
        e.rotation_mode = "QUATERNION"
        e.rotation_quaternion = Matrix(axes.tolist()).to_quaternion()
        e.scale = np.maximum(3.0 * sigma, 0.01).tolist()
        e.location = p.tolist()
        e["somacap_sigma_mm"] = (sigma * 1000.0).tolist()
        e["somacap_scene"] = str(Path(scene_dir).resolve())
        e["somacap_placed"] = p.tolist()
        e["somacap_joint"] = j
        coll.objects.link(e)
        out[j] = e
    return out


def clicked_positions() -> dict:
    """``{joint: xyz (3,)}`` from the (possibly user-edited) click empties."""
    import bpy

    bpy.context.view_layer.update()  # matrix_world of moved/new empties
    return {
        o["somacap_joint"]: np.array(o.matrix_world.translation)
        for o in bpy.data.objects
        if "somacap_joint" in o
    }


def moved_clicks(scene_dir, tol_m: float = 1e-4) -> dict:
    """``{joint: xyz (3,)}`` of the scene's click empties (:func:`place_clicks`) that
    the user has moved more than ``tol_m`` from where they were placed; the fit takes
    them in place of those joints' clicks (:func:`run_fit`)."""
    import bpy

    bpy.context.view_layer.update()
    scene = str(Path(scene_dir).resolve())
    out = {}
    for o in bpy.data.objects:
        if o.get("somacap_scene") != scene or "somacap_placed" not in o:
            continue
        x = np.array(o.matrix_world.translation)
        if np.linalg.norm(x - np.array(o["somacap_placed"])) > tol_m:
            out[o["somacap_joint"]] = x
    return out


def build_take(state, take: str):
    """Armature, metaballs and action of a state; per-frame quality on the armature."""
    arm, balls, action = builders.build_body(state, take=take)
    q = state.quality
    arm["somacap_rmse_mm"] = [float(v) * 1000.0 if np.isfinite(v) else -1.0 for v in q.rmse_m]
    arm["somacap_diverged"] = [int(v) for v in q.diverged]
    return arm, balls, action


def generate_rigify_human(name: str = "rigify_human", location=(0.0, 0.0, 0.0), face: bool = True):
    """A rig generated by Rigify from its human meta-rig; returns the rig object.

    Enables Rigify (bundled with Blender) when needed.  ``face=False`` drops the face
    bones first: generation takes about 2 s instead of 10–25 s; the body rig is the same.
    The meta-rig is deleted afterwards.
    """
    import addon_utils
    import bpy

    if "armature_human_metarig_add" not in dir(bpy.ops.object):
        addon_utils.enable("rigify", default_set=True)
    bpy.ops.object.armature_human_metarig_add()
    meta = bpy.context.active_object
    if not face:
        bpy.ops.object.mode_set(mode="EDIT")
        eb = meta.data.edit_bones
        for b in [
            b for b in eb if b.name == "face" or any(p.name == "face" for p in b.parent_recursive)
        ]:
            eb.remove(b)
        bpy.ops.object.mode_set(mode="OBJECT")
    meta.data.rigify_rig_basename = name
    bpy.ops.pose.rigify_generate()
    rig = bpy.data.objects[name]
    bpy.data.objects.remove(meta)
    rig.location = location
    bpy.context.view_layer.update()
    return rig


def load_character(path):
    """Append every object of a character .blend; returns its main armature object.

    Raises InputError (and removes what it appended) when the file has no armature.
    """
    import bpy

    path = Path(path)
    if not path.is_file():
        raise _core.errors.InputError(f"{path}: character file not found")
    if path.suffix.lower() != ".blend":
        raise _core.errors.InputError(f"{path}: a character must be a .blend file")
    try:
        with bpy.data.libraries.load(str(path), link=False) as (src, dst):
            dst.objects = list(src.objects)
    except OSError as exc:  # e.g. a Blender 5.0 file opened by Blender 4.2
        raise _core.errors.InputError(
            f"{path}: Blender {bpy.app.version_string} cannot read it (saved by a newer "
            f"Blender, or not a .blend file)"
        ) from exc
    objs = [o for o in dst.objects if o is not None]
    arms = [o for o in objs if o.type == "ARMATURE"]
    if not arms:
        for o in objs:
            bpy.data.objects.remove(o)
        raise _core.errors.InputError(f"{path}: has no armature to retarget onto")
    coll = bpy.data.collections.new(f"Character {path.stem}")
    bpy.context.scene.collection.children.link(coll)
    for o in objs:
        coll.objects.link(o)
    return max(arms, key=lambda o: len(o.data.bones))


def export_motion(armature, path, fmt: str | None = None) -> Path:
    """Export the armature's current action with Blender's own BVH or FBX exporter."""
    import bpy

    path = Path(path)
    fmt = (fmt or path.suffix.lstrip(".")).lower()
    path.parent.mkdir(parents=True, exist_ok=True)
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    armature.select_set(True)
    bpy.context.view_layer.objects.active = armature
    scene = bpy.context.scene
    if fmt == "bvh":
        bpy.ops.export_anim.bvh(
            filepath=str(path),
            frame_start=scene.frame_start,
            frame_end=scene.frame_end,
            rotate_mode="NATIVE",
            root_transform_only=True,
        )
    elif fmt == "fbx":
        bpy.ops.export_scene.fbx(
            filepath=str(path),
            use_selection=True,
            object_types={"ARMATURE"},
            bake_anim=True,
            add_leaf_bones=False,
        )
    else:
        raise _core.errors.InputError(f"{path}: export format must be .bvh or .fbx")
    return path


class BackgroundJob:
    """Run ``job(progress)`` in a worker thread; the main thread polls it.

    Blender data must only be touched on the main thread: the job computes plain data
    (e.g. a fitted state), the operator builds Blender objects from ``result`` after
    :attr:`done`.  :meth:`cancel` sets the progress cancel flag; the job stops at its
    next ``progress.update``/``check`` with :class:`core.progress.Cancelled`.
    """

    def __init__(self, job):
        self.fraction = 0.0
        self.message = ""
        self.result = None
        self.error: BaseException | None = None
        self.progress = _core.progress.Progress(callback=self._update)
        self._thread = threading.Thread(target=self._run, args=(job,), daemon=True)

    def _update(self, fraction, message):
        self.fraction, self.message = float(fraction), str(message)

    def _run(self, job):
        try:
            self.result = job(self.progress)
        except BaseException as exc:  # reported on the main thread
            self.error = exc

    def start(self) -> BackgroundJob:
        self._thread.start()
        return self

    @property
    def done(self) -> bool:
        return not self._thread.is_alive()

    def cancel(self) -> None:
        self.progress.cancel()

    def join(self, timeout: float | None = None) -> None:
        self._thread.join(timeout)

    @property
    def cancelled(self) -> bool:
        return isinstance(self.error, _core.progress.Cancelled)
