"""Visibility index of every body part against a reference from the true mesh.

The reference splats the rendered (true, skinned) mesh into each camera: every vertex
and many points per triangle, each labelled with the body part (bone of our skeleton)
whose segment is nearest in the first frame, z-buffered per pixel.  Its visibility
index is visible pixels / pixels covered ignoring occlusion, as in the second paper.
Ours renders the metaball body of a fitted state (:func:`core.model_render.render_parts`).
Used by ``bench/silhouettes.py``.
"""

from __future__ import annotations

import numpy as np

from core.contour_obs import body_ellipsoids
from core.model_render import camera_rays, render_parts
from core.skeleton import Skeleton

MIN_AREA_PX = 80  # parts covering fewer pixels (ignoring occlusion) are not scored


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
        np.einsum("bk,bk->b", ab, ab), 1e-12)
    closest = a[None] + np.clip(t, 0, 1)[..., None] * ab[None]
    d = np.linalg.norm(vertices[:, None] - closest, axis=2)
    return np.argmin(d, axis=1)


def surface_samples(vertices, faces, vpart, per_face: int, rng):
    """Points on the mesh (N, 3) with parts (N,): vertices plus random points per face."""
    w = rng.dirichlet(np.ones(3), size=(len(faces), per_face))  # (T, k, 3)
    pts = np.einsum("tkj,tjd->tkd", w, vertices[faces]).reshape(-1, 3)
    corner = np.argmax(w, axis=2).reshape(-1)
    part = vpart[faces][np.repeat(np.arange(len(faces)), per_face), corner]
    return np.vstack([vertices, pts]), np.concatenate([vpart, part])


def splat_visibility(camera, xyz, part, n_parts):
    """Reference visibility (P,) and full areas (P,) from z-buffered point splats."""
    w, h = camera.size
    uv = camera.project(xyz)
    depth = np.linalg.norm(xyz - camera.center, axis=1)
    ok = np.all(np.isfinite(uv), axis=1)
    iu, iv = np.round(uv[ok, 0]).astype(int), np.round(uv[ok, 1]).astype(int)
    inside = (iu >= 0) & (iu < w) & (iv >= 0) & (iv < h)
    pix = (iv * w + iu)[inside]
    d, p = depth[ok][inside], part[ok][inside]
    full = np.array([np.unique(pix[p == k]).size for k in range(n_parts)])
    order = np.lexsort((d, pix))
    first = np.ones(len(order), bool)
    first[1:] = pix[order][1:] != pix[order][:-1]
    front = p[order][first]
    visible = np.bincount(front, minlength=n_parts)[:n_parts]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(full > 0, visible / full, np.nan), full


def compare(state, truth: dict, cameras, frames, per_face: int = 8, seed: int = 0):
    """Mean |VI_ours - VI_ref| and the agreement of the VI ≥ 0.2 decision.

    Returns a dict with ``mean_abs_diff``, ``decision_agreement``, ``n`` (scored
    part-camera-frame triples) and per-part mean differences.
    """
    rng = np.random.default_rng(seed)
    skel = state.skeleton
    n_parts = len(skel.bone_names)
    names = [str(n) for n in truth["joint_names"]]
    j0 = {n: truth["joints_xyz"][0, i] for i, n in enumerate(names)}
    vpart = vertex_parts(skel, truth["vertices"][0], j0)
    rays = [camera_rays(c) for c in cameras]
    diffs, agree, per_part = [], [], [[] for _ in range(n_parts)]
    for f in frames:
        xyz, part = surface_samples(truth["vertices"][f], truth["faces"], vpart, per_face, rng)
        centers, axes, radii, bone = body_ellipsoids(skel, state.theta[f], state.root_xyz[f],
                                                     state.s, state.metaballs)
        for cam, r in zip(cameras, rays, strict=True):
            ref, full = splat_visibility(cam, xyz, part, n_parts)
            ours = render_parts(cam, centers, axes, radii, bone, n_parts, rays=r)
            vi = ours.visibility_index
            scored = (full >= MIN_AREA_PX) & np.isfinite(vi) & np.isfinite(ref)
            d = np.abs(vi - ref)[scored]
            diffs.extend(d)
            agree.extend(((vi >= 0.2) == (ref >= 0.2))[scored])
            for k in np.flatnonzero(scored):
                per_part[k].append(abs(vi[k] - ref[k]))
    return {
        "mean_abs_diff": float(np.mean(diffs)),
        "decision_agreement": float(np.mean(agree)),
        "n": len(diffs),
        "per_part": {skel.bone_names[k]: float(np.mean(v)) for k, v in enumerate(per_part)
                     if v},
    }
