"""Body-shape benchmark: ``python -m bench.shape [--scene DIR] [--quick]``.

Issue 5 ("the fitted metaball surface against the true mesh: mean distance ≤ 5 mm",
simplified and complete model) and issue 7 (the visibility index against the true
mesh's, mean |ΔVI| ≤ 0.05) for the template shape and for the shape fitted by
:func:`core.shape_fit.fit_shape`.

Poses are the truth's (:func:`core.truth_state.truth_to_state`, exact joints), so the
figures measure the *shape* alone.  The shape is fitted to **truth-derived surface
points** (:mod:`core.truth_points`: points of the true mesh seen by two cameras,
1.5 mm noise, 5 % gross outliers) of a few frames — a stand-in for the tracker's
points, labelled as such.  Beside it, the row ``mesh`` fits the same model to the
*whole* true mesh of those frames (area samples, no noise, front and back): what the
metaball model itself can reach, against which the targets can be read.  The
distances are measured on other frames as well:

* metaball → mesh: points on the whole-body iso-surface ``Σ f = 0.5``
  (:func:`core.metaball_surface.sample_surface`) to the nearest point of the true mesh
  (:func:`bench.meshtruth.nearest_on_mesh`);
* mesh → metaball: every other true vertex to the iso-surface — the shorter of two
  upper bounds of the distance: the Newton projection along the field gradient
  (:func:`core.metaball_surface.project_to_surface`, not the shortest path far from the
  surface) and the nearest of dense surface samples (too long by the spacing).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from bench.meshtruth import nearest_on_mesh
from core.metaball_surface import project_to_surface, sample_surface
from core.metaballs import Metaballs, make_metaballs, world_frames
from core.skeleton import Skeleton, forward

REPO = Path(__file__).resolve().parents[1]
MESH_POINTS = 4000  # area samples of the whole true mesh per frame (the capacity row)


def _capacity_settings():
    """Shape-fit settings with the whole mesh as data: the penalty against bulging on
    every model point, seen or not (``min_views`` 0: every side has data; without it
    the surface swells freely where no data point pulls, 18.7 mm metaball -> mesh on
    walk_line3), no symmetry (the true body need not be symmetric), wide bounds."""
    from core.shape_fit import ShapeSettings

    return ShapeSettings(model_points=True, min_views=0, sigma_symmetry=0.0, radius_ratio=4.0)


def seen_vertices(vertices: np.ndarray, faces: np.ndarray, cameras, min_views: int = 2):
    """(V,) bool: vertices of the mesh that ``min_views`` cameras see, judged as
    :mod:`core.truth_points` judges the points it makes (depth map, viewing angle)."""
    from core.truth_points import depth_map, visible

    v = np.asarray(vertices, float)
    tri = v[np.asarray(faces, int)]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    vn = np.zeros_like(v)
    for k in range(3):
        np.add.at(vn, np.asarray(faces, int)[:, k], fn)
    vn /= np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-300)
    views = sum(visible(cam, v, vn, depth_map(cam, tri)).astype(int) for cam in cameras)
    return views >= min_views


def surface_distances(
    skel: Skeleton,
    theta: np.ndarray,
    root_xyz: np.ndarray,
    s: np.ndarray,
    balls: Metaballs,
    vertices: np.ndarray,
    faces: np.ndarray,
    per_ball: int = 150,
    vertex_step: int = 2,
    seed: int = 0,
) -> dict:
    """Distances between the metaball surface of one pose and a triangle mesh.

    Parameters
    ----------
    theta : (n,) radians; root_xyz : (3,) metres; s : (G,)
    vertices : (V, 3) world metres; faces : (T, 3) int — the true mesh of that frame
    vertex_step : use every ``vertex_step``-th vertex for mesh → metaball

    Returns
    -------
    dict with ``ball_to_mesh`` (K,) and ``mesh_to_ball`` (V',) distances in metres,
    ``ball_bone`` (K,) the bone of the metaball each surface sample started from and
    ``vertex_idx`` (V',) the vertices measured.
    """
    pose = forward(skel, np.asarray(theta, float)[None], np.asarray(root_xyz, float)[None], s)
    x, ok = sample_surface(skel, pose, balls, s, per_ball=per_ball, seed=seed)
    bone = np.repeat(balls.bone, per_ball)[ok]
    x = x[ok]
    v = np.asarray(vertices, float)
    d_bm, _, _ = nearest_on_mesh(x, v, np.asarray(faces, int))
    Rw, cw = world_frames(skel, pose, balls, s)
    vi = np.arange(0, len(v), max(int(vertex_step), 1))
    xs, conv = project_to_surface(v[vi], Rw[0], cw[0], balls.radii)
    d_mb = np.where(conv, np.linalg.norm(xs - v[vi], axis=1), np.inf)
    d_mb = np.minimum(d_mb, cKDTree(x).query(v[vi])[0])
    return {"ball_to_mesh": d_bm, "mesh_to_ball": d_mb, "ball_bone": bone, "vertex_idx": vi}


def shape_table(
    scene_dir: Path,
    fit_frames: list[int],
    eval_frames: list[int],
    n_points: int,
    models: tuple[str, ...],
    vis_step: int | None,
):
    from bench.visibility import compare
    from core.evaluate import sample_mesh_surface
    from core.scene import load_scene
    from core.shape_fit import fit_shape
    from core.truth_points import sample_frame
    from core.truth_state import truth_to_state

    scene = load_scene(scene_dir)
    cams = scene.calibration()
    state, _ = truth_to_state(scene.truth, scene.fps)
    skel, s = state.skeleton, state.s
    faces = np.asarray(scene.truth["faces"], int)
    verts = scene.truth["vertices"]
    rng = np.random.default_rng(0)
    pts = [sample_frame(verts[f].astype(float), faces, cams, n_points, rng)[0] for f in fit_frames]
    mesh_pts = [sample_mesh_surface(verts[f], faces, MESH_POINTS, rng) for f in fit_frames]
    print(
        f"\nShape on {scene.name}: truth poses; fitted to truth-derived surface points of "
        f"frames {fit_frames} ({', '.join(str(len(p)) for p in pts)} points seen by 2 "
        f"cameras, 1.5 mm noise, 5 % outliers); distances on frames {eval_frames}"
    )
    seen = {f: seen_vertices(verts[f], faces, cams) for f in eval_frames}
    print(
        f"{'model':11s} {'shape':9s} {'M':>3s} {'ball->mesh mm':>14s} {'mesh->ball mm':>14s} "
        f"{'symmetric':>9s} {'seen mesh':>9s} {'fit s':>6s}  note"
    )
    results = {}
    for model in models:
        template = make_metaballs(skel, model, s)
        t0 = time.perf_counter()
        fit = fit_shape(
            skel, template, s, state.theta[fit_frames], state.root_xyz[fit_frames], pts, cams
        )
        t_fit = time.perf_counter() - t0
        # the model's capacity: the same fit with the whole true mesh as its data
        t0 = time.perf_counter()
        floor = fit_shape(
            skel,
            template,
            s,
            state.theta[fit_frames],
            state.root_xyz[fit_frames],
            mesh_pts,
            cams,
            settings=_capacity_settings(),
        )
        t_floor = time.perf_counter() - t0
        for label, balls in (
            ("template", template),
            ("fitted", fit.metaballs),
            ("mesh", floor.metaballs),
        ):
            bm, mb, sn = [], [], []
            for f in eval_frames:
                d = surface_distances(
                    skel, state.theta[f], state.root_xyz[f], s, balls, verts[f], faces
                )
                bm.append(d["ball_to_mesh"])
                mb.append(d["mesh_to_ball"])
                sn.append(seen[f][d["vertex_idx"]])
            bm, mb, sn = 1e3 * np.concatenate(bm), 1e3 * np.concatenate(mb), np.concatenate(sn)
            note = {"fitted": fit.message, "mesh": f"capacity: {floor.message}"}.get(label, "")
            tf = {"fitted": f"{t_fit:6.1f}", "mesh": f"{t_floor:6.1f}"}.get(label, f"{'':6s}")
            print(
                f"{model:11s} {label:9s} {len(balls):3d} {bm.mean():8.1f} ({np.median(bm):4.1f})"
                f" {mb.mean():8.1f} ({np.median(mb):4.1f}) {0.5 * (bm.mean() + mb.mean()):9.1f}"
                f" {mb[sn].mean():9.1f} {tf}  {note}"
            )
            results[(model, label)] = balls
    print(
        "   (mean, median in brackets; symmetric = the average of both directions; seen mesh ="
        " mesh -> ball over the vertices two cameras see; 'mesh' = fitted to the whole true"
        f" mesh, {MESH_POINTS} points by area per frame, no noise: what the model can reach)"
    )
    if vis_step is None:
        return results
    vis_frames = range(0, scene.n_frames, vis_step)
    print(
        f"\nVisibility index vs the true mesh, frames {list(vis_frames)} x {len(cams)} cameras "
        f"(truth poses)"
    )
    print(
        f"{'model':11s} {'shape':9s} {'mesh labels':11s} {'our render':10s} {'mean |dVI|':>10s} "
        f"{'VI>=0.2 agree':>14s} {'n':>5s}   worst parts"
    )
    for (model, label), balls in results.items():
        st = _with_balls(state, balls)
        for labels, surface in (("segments", "lone"), ("model", "lone"), ("model", "blend")):
            r = compare(st, scene.truth, cams, vis_frames, labels=labels, surface=surface)
            worst = sorted(r["per_part"].items(), key=lambda kv: -kv[1])[:3]
            print(
                f"{model:11s} {label:9s} {labels:11s} {surface:10s} {r['mean_abs_diff']:10.3f} "
                f"{100 * r['decision_agreement']:13.1f}% {r['n']:5d}   "
                + ", ".join(f"{k} {v:.3f}" for k, v in worst)
            )
    print(
        "   mesh labels: 'segments' = nearest bone segment (the earlier reference), 'model' ="
        " the model's own part boundaries; our render: 'lone' = each metaball's lone"
        " ellipsoid (as core.contour_obs renders now), 'blend' = core.metaball_surface.render_radii"
    )
    return results


def _with_balls(state, balls):
    from dataclasses import replace

    return replace(state, metaballs=balls)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", type=Path, default=REPO / "sample_scenes" / "walk_line3")
    ap.add_argument("--fit-frames", default="0,17,34", help="frames whose points fit the shape")
    ap.add_argument("--eval-frames", default="0,25,45")
    ap.add_argument("--points", type=int, default=10000, help="candidate points per frame")
    ap.add_argument("--models", default="simplified,complete")
    ap.add_argument("--no-visibility", action="store_true")
    ap.add_argument("--vis-step", type=int, default=5, help="every n-th frame for the VI")
    args = ap.parse_args(argv)
    fit_frames = [int(v) for v in args.fit_frames.split(",")]
    eval_frames = [int(v) for v in args.eval_frames.split(",")]
    shape_table(
        args.scene,
        fit_frames,
        eval_frames,
        args.points,
        tuple(args.models.split(",")),
        None if args.no_visibility else args.vis_step,
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
