"""Seeded contour scenes for the contour fit tests: cameras, a posed body, its silhouettes."""

from __future__ import annotations

import numpy as np

from core import metaballs as mb
from core import skeleton as sk
from core.contour_obs import body_ellipsoids
from core.contours import occluding_contours
from core.model_render import render_parts
from tests.core._bodyscene import look_at


def _cams():
    """Three cameras around the subject (front, side, diagonal), 512x384."""
    t = (0.0, 0.0, 1.0)
    return [
        look_at(f"cam0{i + 1}", c, t, f=700.0)
        for i, c in enumerate(((0.0, -4.0, 1.1), (4.0, 0.0, 1.1), (-2.8, -2.8, 1.1)))
    ]


def _silhouettes(skel, balls, theta, root, s, cams):
    """Occluding contours (per camera) of the model's own rendered silhouette."""
    c, a, r, p = body_ellipsoids(skel, theta, root, s, balls)
    return [occluding_contours(render_parts(cam, c, a, r, p).mask, spacing=1.5) for cam in cams]


def _pose(skel):
    theta = np.zeros(skel.n_dof)
    for name, val in (
        ("l_shoulder_y", -0.8),
        ("r_shoulder_y", 0.9),
        ("l_elbow_x", -0.6),
        ("r_knee_x", 0.5),
        ("r_hip_x", -0.4),
        ("l_hip_y", -0.25),
    ):
        theta[skel.dof_index(name)] = val
    return theta, np.array([0.0, 0.0, 1.0])


def _motion(nf):
    """Skeleton, scales, simplified metaballs and nf frames (nf, n) of :func:`_pose`."""
    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    base, _ = _pose(skel)
    return skel, s, mb.make_metaballs(skel, "simplified", s), np.repeat(base[None], nf, axis=0)
