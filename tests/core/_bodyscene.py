"""Seeded synthetic body scenes for the fit tests: cameras, a posed model, its points."""

from __future__ import annotations

import numpy as np

from core import metaball_surface as mbs
from core import metaballs as mb
from core import skeleton as sk
from core.camera import Camera
from core.model_render import render_parts


def look_at(name: str, center, target=(0.0, 0.0, 1.0), f: float = 600.0) -> Camera:
    """A 512x384 pinhole camera at ``center`` looking at ``target`` (world Z up)."""
    center, target = np.asarray(center, float), np.asarray(target, float)
    z = target - center
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    K = [[f, 0, 255.5], [0, f, 191.5], [0, 0, 1]]
    return Camera(name, (512, 384), K, np.zeros(5), R, -R @ center)


def cameras() -> list[Camera]:
    """Three cameras in a line in front of the subject (who faces −Y)."""
    return [look_at(f"cam0{i + 1}", (x, -4.0, 1.2)) for i, x in enumerate((-1.5, 0.0, 1.5))]


def model_points(skel, balls, theta, root, s, rng, per_bone=20):
    """Points (N, 3) on each part's own iso-surface with their part labels (N,)."""
    pose = sk.forward(skel, theta[None], root[None], s)
    Rw, cw = mb.world_frames(skel, pose, balls, s)
    xyz, part = [], []
    for b in np.unique(balls.bone):
        on = balls.bone == b
        m = rng.choice(np.nonzero(on)[0], per_bone)
        u = rng.normal(size=(per_bone, 3))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        x0 = np.einsum("nij,nj->ni", Rw[0, m], u * balls.radii[m] * mb.VISIBLE) + cw[0, m]
        x, ok = mbs.project_to_surface(x0, Rw[0, on], cw[0, on], balls.radii[on])
        xyz.append(x[ok])
        part.append(np.full(ok.sum(), b))
    return np.concatenate(xyz), np.concatenate(part)


def clicks_of(skel, theta, root, s, cams, joints) -> dict:
    """clicks.json content: the model's joints projected into every camera."""
    x = sk.joint_positions(skel, theta, root, s)
    out = {}
    for j in joints:
        out[j] = {c.name: c.project(x[skel.joint_index(j)][None])[0] for c in cams}
    return {"frame": 0, "joints": out}


def textured_render(skel, balls, theta, root, s, cam, rays, seed=0):
    """(H, W) uint8: the body at a pose with a texture fixed in each bone's frame
    (wavelengths 4–7 cm), on a flat grey background."""
    pose = sk.forward(skel, theta[None], root[None], s)
    Rw, cw = mb.world_frames(skel, pose, balls, s)
    ren = render_parts(
        cam, cw[0], Rw[0], balls.visible, balls.bone, len(skel.bone_names), rays=rays
    )
    img = np.full(ren.part_id.shape, 90.0)
    v, u = np.nonzero(ren.part_id >= 0)
    b = ren.part_id[v, u]
    x = cam.center + ren.depth[v, u, None] * rays[v, u]
    Rb, pb = sk.bone_frames(skel, pose)
    q = np.einsum("nji,nj->ni", Rb[0, b], x - pb[0, b])
    rng = np.random.default_rng(seed)
    val = np.full(len(b), 128.0)
    for _ in range(4):
        k = rng.normal(size=3)
        k *= 2 * np.pi / rng.uniform(0.04, 0.07) / np.linalg.norm(k)
        val += 25.0 * np.sin(q @ k + rng.uniform(0, 2 * np.pi) + b)
    img[v, u] = val
    return np.clip(img, 0, 255).astype(np.uint8)
