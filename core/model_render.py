"""Render a body of ellipsoids into a camera: per-part masks with and without occlusion.

This is what the visibility index of the second paper needs (SPEC.md stage 6): for
each body part and camera, the area the part covers when the other parts are
ignored, and the area where it is the front-most surface.  Each ellipsoid is
splatted exactly: for every pixel of its projected bounding box the viewing ray is
intersected with the ellipsoid in closed form, and a z-buffer keeps the nearest
surface.  A metaball ``exp(-2 d)`` with threshold ``T`` on its own has the surface
``d = -ln(T) / 2``, i.e. the ellipsoid with radii scaled by ``sqrt(-ln(T) / 2)``
(0.589 for T = 0.5); callers pass the radii they want rendered.

Frames: world Z up, metres; cameras as in :mod:`core.camera` (distortion honoured
through the undistorted viewing ray of every pixel).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera import Camera


@dataclass
class PartRender:
    """Rendering of one camera.

    Attributes
    ----------
    part_id : ndarray, shape (H, W), int
        Front-most part at each pixel, -1 for background.
    depth : ndarray, shape (H, W), float
        Depth along the viewing ray of the front-most surface, metres (inf: none).
    full_area : ndarray, shape (P,), int
        Pixels each part covers when occlusion is ignored.
    visible_area : ndarray, shape (P,), int
        Pixels where each part is the front-most surface.
    """

    part_id: np.ndarray
    depth: np.ndarray
    full_area: np.ndarray
    visible_area: np.ndarray

    @property
    def visibility_index(self) -> np.ndarray:
        """Visible projected area / projected area ignoring occlusion, shape (P,).

        NaN for a part that projects to no pixel (outside the image).
        """
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self.full_area > 0, self.visible_area / self.full_area, np.nan)

    @property
    def mask(self) -> np.ndarray:
        """Silhouette of the whole body, ``(H, W)`` bool."""
        return self.part_id >= 0


def _ray_grid(camera: Camera, step: int = 1) -> np.ndarray:
    w, h = camera.size
    vv, uu = np.mgrid[0:h:step, 0:w:step]
    uv = np.stack([uu, vv], axis=-1).astype(float)
    _, d = camera.rays(uv)
    return d  # (h, w, 3) unit world directions


def render_parts(
    camera: Camera,
    centers: np.ndarray,
    axes: np.ndarray,
    radii: np.ndarray,
    part: np.ndarray,
    n_parts: int | None = None,
    rays: np.ndarray | None = None,
    outer_only: bool = False,
    buried_by: np.ndarray | None = None,
) -> PartRender:
    """Render ellipsoids into ``camera`` with a z-buffer.

    Parameters
    ----------
    camera : Camera
    centers : ndarray, shape (E, 3)
        Ellipsoid centres, world metres.
    axes : ndarray, shape (E, 3, 3)
        Rotation of each ellipsoid: columns are its principal axes in world coordinates.
    radii : ndarray, shape (E, 3)
        Semi-axes along those axes, metres.
    part : ndarray, shape (E,), int
        Body-part index of each ellipsoid (several ellipsoids may share a part).
    n_parts : int, optional
        Number of parts P (default ``part.max() + 1``).
    rays : ndarray, shape (H, W, 3), optional
        Precomputed unit viewing directions (see :func:`camera_rays`) to save time
        when rendering many frames from one camera.
    outer_only : bool
        Count in ``full_area`` only pixels where the part's surface (the ray's entry or
        exit point of one of its ellipsoids) lies on the body's outer surface, i.e.
        inside no other ellipsoid.  Overlapping ellipsoids bury much of a small part
        (a clavicle inside the chest and shoulder, a wrist inside the forearm and
        hand); the buried surface is not skin, and counting it as "area ignoring
        occlusion" drove the visibility index of small parts below that of the
        true mesh's parts.  ``part_id``, ``depth`` and ``visible_area`` are unchanged
        (a buried point is never the front-most one).
    buried_by : ndarray, shape (P, P), bool, optional
        With ``outer_only``: ``buried_by[a, b]`` — a surface point of part ``a`` inside
        an ellipsoid of part ``b`` counts as buried (default: any part).  Passing the
        parts' kinematic neighbours (:func:`neighbour_parts`) treats only the overlap
        at joints as buried, and a limb resting against the trunk as contact (skin
        exists under it, as on the true body).

    Returns
    -------
    PartRender
    """
    centers = np.asarray(centers, float)
    axes = np.asarray(axes, float)
    radii = np.asarray(radii, float)
    part = np.asarray(part, int)
    n_parts = int(part.max()) + 1 if n_parts is None else n_parts
    w, h = camera.size
    d_all = _ray_grid(camera) if rays is None else rays
    origin = camera.center
    depth = np.full((h, w), np.inf)
    part_id = np.full((h, w), -1, int)
    full_area = np.zeros(n_parts, int)
    covered = np.zeros((n_parts, h, w), bool) if n_parts <= 64 else None

    # projected bounding boxes from the 8 corners of each ellipsoid's box
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    A_all = np.transpose(axes, (0, 2, 1)) / radii[:, :, None]  # world -> unit sphere
    reach = radii.max(axis=1)
    near = np.linalg.norm(centers[:, None] - centers[None], axis=2) < reach[:, None] + reach[None]
    pts = centers[:, None, :] + np.einsum("eij,ekj->eki", axes, corners[None] * radii[:, None, :])
    uv = camera.project(pts.reshape(-1, 3)).reshape(len(centers), 8, 2)
    cam_z = camera.to_camera(pts.reshape(-1, 3))[:, 2].reshape(len(centers), 8)
    for e in range(len(centers)):
        if np.any(cam_z[e] <= 1e-6) or not np.all(np.isfinite(uv[e])):
            # behind or straddling the camera: test the whole image (rare)
            u0, v0, u1, v1 = 0, 0, w - 1, h - 1
        else:
            u0 = max(int(np.floor(uv[e, :, 0].min())) - 1, 0)
            v0 = max(int(np.floor(uv[e, :, 1].min())) - 1, 0)
            u1 = min(int(np.ceil(uv[e, :, 0].max())) + 1, w - 1)
            v1 = min(int(np.ceil(uv[e, :, 1].max())) + 1, h - 1)
        if u0 > u1 or v0 > v1:
            continue
        d = d_all[v0 : v1 + 1, u0 : u1 + 1]  # (bh, bw, 3)
        # ray o + s d in the ellipsoid's unit-sphere frame: q(s) = A (o - c) + s A d
        A = axes[e].T / radii[e][:, None]  # world -> scaled local
        oc = A @ (origin - centers[e])
        dl = d @ A.T
        a = np.einsum("hwk,hwk->hw", dl, dl)
        b = 2.0 * dl @ oc
        c = oc @ oc - 1.0
        disc = b * b - 4.0 * a * c
        hit = disc >= 0
        sq = np.sqrt(np.where(hit, disc, 0.0))
        s_near = (-b - sq) / (2.0 * a)
        s_far = (-b + sq) / (2.0 * a)
        s = np.where(s_near > 0, s_near, s_far)
        hit &= s > 0
        if not hit.any():
            continue
        p = part[e]
        full_area_box = hit
        if outer_only:
            others = np.flatnonzero(near[e])
            others = others[others != e]
            if buried_by is not None:
                others = others[np.asarray(buried_by, bool)[part[e], part[others]]]
            if len(others):
                full_area_box = hit & (
                    _outer(origin, d, s_near, others, A_all, centers)
                    | _outer(origin, d, s_far, others, A_all, centers)
                )
        if covered is not None:
            covered[p, v0 : v1 + 1, u0 : u1 + 1] |= full_area_box
        sub_depth = depth[v0 : v1 + 1, u0 : u1 + 1]
        closer = hit & (s < sub_depth)
        sub_depth[closer] = s[closer]
        part_id[v0 : v1 + 1, u0 : u1 + 1][closer] = p
    if covered is not None:
        full_area = covered.reshape(n_parts, -1).sum(axis=1)
    visible_area = np.bincount(part_id[part_id >= 0], minlength=n_parts)[:n_parts]
    return PartRender(part_id, depth, full_area, visible_area)


def _outer(origin, d, s, others, A_all, centers, shrink: float = 0.995) -> np.ndarray:
    """Whether the points ``origin + s d`` (h, w) lie inside none of ``others``."""
    x = origin + np.where(np.isfinite(s), s, 0.0)[..., None] * d  # (h, w, 3)
    q = np.einsum("oij,hwoj->hwoi", A_all[others], x[:, :, None, :] - centers[others])
    return ~np.any(np.einsum("hwoi,hwoi->hwo", q, q) < shrink**2, axis=2) & (s > 0)


def neighbour_parts(parent: np.ndarray) -> np.ndarray:
    """(P, P) bool: each part, its parent and its children (``parent`` (P,), -1 for none)."""
    parent = np.asarray(parent, int)
    P = len(parent)
    adj = np.eye(P, dtype=bool)
    child = np.flatnonzero(parent >= 0)
    adj[child, parent[child]] = adj[parent[child], child] = True
    return adj


def camera_rays(camera: Camera) -> np.ndarray:
    """Unit world viewing directions of every pixel, shape (H, W, 3)."""
    return _ray_grid(camera)
