"""Visibility index of every body part against a reference from the true mesh.

The reference rasterises the rendered (true, skinned) mesh into each camera at pixel
centres with a z-buffer (:mod:`bench.mesh_raster`; its silhouettes match the studio's
rendered masks to IoU 0.997), every fragment labelled with a body part (bone of our
skeleton).  It samples the image as our renderer does, one ray per pixel centre: the
earlier reference splatted random surface points to their nearest pixels, which
dilates every part by up to half a pixel along its outline and drifted with the
sample count.  Its visibility index is visible pixels / pixels covered
ignoring occlusion, as in the second paper.  Ours renders the metaball body of a
fitted state (:func:`core.model_render.render_parts`).  Used by ``bench/silhouettes.py``
and ``bench/shape.py``.

Part labels of the true mesh (``labels``):

* ``"model"`` (default) — the model's own part boundaries: each vertex takes the bone of
  the rendered ellipsoid whose surface is nearest to it in that frame
  (:func:`core.segment.surface_distance`), which is how the rendering splits the body
  between parts (the front-most ellipsoid wins a pixel).  The reference then differs
  from ours only where the body's *shape* differs;
* ``"segments"`` — the nearest bone *segment* in the first frame (the earlier
  definition).  Its boundaries are not the model's: the hip girdle ellipsoid covers
  the buttocks that the segment rule gives to the thighs, the clavicle ellipsoids the
  shoulder tops, the trunk ellipsoids overlap the upper arms' roots, etc., so it adds a
  part-boundary mismatch to |ΔVI| even for a perfect shape (on walk_line3 with the
  template shape: 0.134 with these labels, 0.093 with the model's).

Our rendering (``surface``): ``"lone"`` (default) — each metaball's lone visible
ellipsoid, as :func:`core.contour_obs.body_ellipsoids` renders it for the camera
selection; ``"blend"`` — ellipsoids that follow the blended whole-body surface
(:func:`core.metaball_surface.render_radii`), right for a shape fitted to surface points
(:mod:`core.shape_fit`), whose metaballs are often small and overlap.

Our area ignoring occlusion (``outer_only``): the whole of each ellipsoid, as the camera
selection renders it, or only the part's outer surface — where a point of its
ellipsoid lies inside any other ellipsoid of the body it is not skin.  Earlier only a
kinematic neighbour at least as large buried a part's surface; on the fitted bodies
``core fit`` writes that left 0.065 / 0.070 (walk_line3 / jumps_line3), any ellipsoid
0.046 / 0.047; the template at the truth pose hardly moves (0.065 → 0.066 / 0.066).

``python -m bench.visibility SCENE [FIT.json ...]`` prints both for the template at the
truth pose and for each fitted state (``core fit … -o FIT.json``; ``make demo`` writes
``out/demo/fit.json``).
"""

from __future__ import annotations

import numpy as np

from core.contour_obs import body_ellipsoids
from core.model_render import camera_rays, render_parts
from core.skeleton import Skeleton

MIN_AREA_PX = 80  # parts covering fewer pixels (ignoring occlusion) are not scored
HEADER = f"{'body':28s} {'our area':16s} {'mean |dVI|':>10s} {'VI>=0.2 agree':>14s} {'n':>5s}"


def _segments(skel: Skeleton, joints: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Head and tail (B, 3) of every bone's segment; the pelvis is the hip girdle."""
    heads, tails = [], []
    for b, name in enumerate(skel.bone_names):
        if name == "pelvis":
            head, tail = joints["l_hip"], joints["r_hip"]
        else:
            head = joints["pelvis" if name == "lowerback" else name]
            tail = joints[skel.bone_tail[b]]
        heads.append(head)
        tails.append(tail)
    return np.array(heads), np.array(tails)


def vertex_parts(skel: Skeleton, vertices: np.ndarray, joints: dict[str, np.ndarray]):
    """Part (bone index) of each vertex (V,): the nearest bone segment."""
    a, b = _segments(skel, joints)
    ab = b - a
    t = np.einsum("vbk,bk->vb", vertices[:, None] - a[None], ab) / np.maximum(
        np.einsum("bk,bk->b", ab, ab), 1e-12
    )
    closest = a[None] + np.clip(t, 0, 1)[..., None] * ab[None]
    d = np.linalg.norm(vertices[:, None] - closest, axis=2)
    return np.argmin(d, axis=1)


def body_render(state, frame: int, surface: str = "lone"):
    """Ellipsoids rendering the state's body at ``frame``: centres (M, 3), axes (M, 3, 3),
    semi-axes (M, 3) and parts (M,).

    ``surface``: ``"blend"`` — axes approximating the whole-body iso-surface
    (:func:`core.metaball_surface.render_radii`); ``"lone"`` — each metaball's lone visible
    ellipsoid (what :func:`core.contour_obs.body_ellipsoids` renders).
    """
    from core.metaball_surface import render_radii
    from core.skeleton import forward

    if surface not in ("blend", "lone"):
        raise ValueError(f"unknown surface {surface!r}")
    skel, balls = state.skeleton, state.metaballs
    centers, axes, radii, bone = body_ellipsoids(
        skel, state.theta[frame], state.root_xyz[frame], state.s, balls
    )
    if surface == "blend":
        pose = forward(skel, state.theta[frame][None], state.root_xyz[frame][None], state.s)
        radii = render_radii(skel, pose, balls, state.s)
    else:
        radii = balls.visible
    return centers, axes, radii, bone


def model_vertex_parts(vertices: np.ndarray, centers, axes, radii, bone) -> np.ndarray:
    """Part (bone index) of each vertex (V,) by the model's own part boundaries: the
    part of the rendered ellipsoid (:func:`body_render`) whose surface is nearest
    (:func:`core.segment.surface_distance`)."""
    from core.segment import surface_distance

    d = surface_distance(np.asarray(vertices, float), axes, centers, radii)
    return bone[np.argmin(d, axis=1)]


def mesh_visibility(camera, vertices, faces, vpart, n_parts):
    """Reference visibility (P,) and full areas (P,) of the labelled true mesh.

    The mesh is rasterised exactly at pixel centres with a z-buffer
    (:mod:`bench.mesh_raster`), as our renderer samples the ellipsoids; each fragment
    takes the part of its triangle's corner nearest to it (``vpart`` (V,) int).
    """
    from bench.mesh_raster import part_visibility, rasterize

    pix, depth, tri, bary = rasterize(camera, vertices, faces)
    part = np.asarray(vpart)[np.asarray(faces)[tri, np.argmax(bary, axis=1)]]
    return part_visibility(pix, depth, part, n_parts)


def compare(
    state,
    truth: dict,
    cameras,
    frames,
    labels: str = "model",
    surface: str = "lone",
    outer_only: bool = False,
):
    """Mean |VI_ours - VI_ref| and the agreement of the VI ≥ 0.2 decision.

    ``labels``: how the true mesh is split into parts, ``"model"`` or ``"segments"``
    (see the module docstring); ``surface``: how our body is rendered, see
    :func:`body_render`; ``outer_only``: our area ignoring occlusion counts only the
    parts' outer surface, like the mesh's: a point of a part's ellipsoid inside any
    other ellipsoid of the body is not skin (:func:`core.model_render.render_parts`).

    Returns a dict with ``mean_abs_diff``, ``decision_agreement``, ``n`` (scored
    part-camera-frame triples), per-part mean differences (``per_part``, ``per_part_n``)
    and per-camera ones (``per_camera``: camera name -> (mean |ΔVI|, the worst part and
    its mean there)).
    """
    if labels not in ("model", "segments"):
        raise ValueError(f"unknown part labels {labels!r}")
    skel = state.skeleton
    n_parts = len(skel.bone_names)
    names = [str(n) for n in truth["joint_names"]]
    j0 = {n: truth["joints_xyz"][0, i] for i, n in enumerate(names)}
    vpart = vertex_parts(skel, truth["vertices"][0], j0)
    rays = [camera_rays(c) for c in cameras]
    diffs, agree, per_part = [], [], [[] for _ in range(n_parts)]
    per_cam = [[[] for _ in range(n_parts)] for _ in cameras]
    for f in frames:
        centers, axes, radii, bone = body_render(state, f, surface)
        if labels == "model":
            vpart = model_vertex_parts(truth["vertices"][f], centers, axes, radii, bone)
        for c, (cam, r) in enumerate(zip(cameras, rays, strict=True)):
            ref, full = mesh_visibility(cam, truth["vertices"][f], truth["faces"], vpart, n_parts)
            ours = render_parts(
                cam,
                centers,
                axes,
                radii,
                bone,
                n_parts,
                rays=r,
                outer_only=outer_only,
            )
            vi = ours.visibility_index
            scored = (full >= MIN_AREA_PX) & np.isfinite(vi) & np.isfinite(ref)
            d = np.abs(vi - ref)[scored]
            diffs.extend(d)
            agree.extend(((vi >= 0.2) == (ref >= 0.2))[scored])
            for k in np.flatnonzero(scored):
                per_part[k].append(abs(vi[k] - ref[k]))
                per_cam[c][k].append(abs(vi[k] - ref[k]))
    per_camera = {}
    for cam, parts in zip(cameras, per_cam, strict=True):
        means = {skel.bone_names[k]: float(np.mean(v)) for k, v in enumerate(parts) if v}
        if means:
            worst = max(means, key=means.get)
            per_camera[cam.name] = (float(np.mean(np.concatenate(parts))), worst, means[worst])
    return {
        "mean_abs_diff": float(np.mean(diffs)),
        "decision_agreement": float(np.mean(agree)),
        "n": len(diffs),
        "per_part": {skel.bone_names[k]: float(np.mean(v)) for k, v in enumerate(per_part) if v},
        "per_part_n": {skel.bone_names[k]: len(v) for k, v in enumerate(per_part)},
        "per_camera": per_camera,
    }


def report(label: str, state, scene, frames) -> None:
    """Print mean |ΔVI|, the VI ≥ 0.2 decision's agreement, the scored part-views and
    the worst parts of ``state`` over ``frames`` of ``scene``, whole ellipsoids and
    outer surface; then, for the outer surface, each camera's mean |ΔVI| and its worst
    part (a camera looking down the trunk stacks its parts along the view)."""
    cams = scene.calibration()
    for outer, how in ((False, "whole ellipsoids"), (True, "outer surface")):
        r = compare(state, scene.truth, cams, frames, outer_only=outer)
        worst = sorted(r["per_part"].items(), key=lambda kv: -kv[1])[:4]
        print(
            f"{label:28s} {how:16s} {r['mean_abs_diff']:10.3f} "
            f"{100 * r['decision_agreement']:12.1f} % {r['n']:5d}   "
            + ", ".join(f"{k} {v:.3f}" for k, v in worst)
        )
    print(
        f"{'':28s} {'per camera':16s} "
        + ", ".join(f"{c} {m:.3f} ({p} {w:.3f})" for c, (m, p, w) in r["per_camera"].items())
    )


def main(argv=None) -> int:
    """Mean |VI ours − VI truth| of the template at the truth pose and of fitted states."""
    import argparse
    from pathlib import Path

    from core.scene import load_scene
    from core.state import read_state
    from core.truth_state import truth_to_state

    ap = argparse.ArgumentParser(description=main.__doc__)
    ap.add_argument("scene", type=Path, help="studio scene with truth.npz (mesh included)")
    ap.add_argument("fits", type=Path, nargs="*", help="fitted states of the scene")
    ap.add_argument("--step", type=int, default=5, help="every STEP-th frame (default 5)")
    args = ap.parse_args(argv)
    scene = load_scene(args.scene, check_images=False)
    frames = range(0, scene.n_frames, args.step)
    print(
        f"Visibility index vs the true mesh, {args.scene.name}, {len(frames)} frames x "
        f"{len(scene.cameras)} cameras (target: mean |dVI| <= 0.05)"
    )
    print(HEADER)
    report("template, truth pose", truth_to_state(scene.truth, scene.fps)[0], scene, frames)
    for fit in args.fits:
        report(fit.name, read_state(fit), scene, frames)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
