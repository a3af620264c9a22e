"""Render a body of ellipsoids into a camera: per-part masks with and without occlusion.

This is what the visibility index of the second paper needs (SPEC.md stage 6): for
each body part and camera, the area the part covers when the other parts are
ignored, and the area where it is the front-most surface.  Each ellipsoid is
splatted exactly: for every pixel of its projected bounding box the viewing ray is
intersected with the ellipsoid in closed form, and a z-buffer keeps the nearest
surface.  A metaball ``exp(-2 d)`` with threshold ``T`` on its own has the surface
``d = -ln(T) / 2``, i.e. the ellipsoid with radii scaled by ``sqrt(-ln(T) / 2)``
(0.589 for T = 0.5); callers pass the radii they want rendered.

The rendering loop itself is :mod:`core.render_kernel`: compiled with numba where it
is available (the same arrays as its numpy path, bit for bit), else numpy.

Frames: world Z up, metres; cameras as in :mod:`core.camera` (distortion honoured
through the undistorted viewing ray of every pixel).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import render_kernel
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
        With ``full_area`` all zero when P > 64.

    Notes
    -----
    Runs :func:`core.render_kernel.render_compiled` (numba) where it can, else
    :func:`core.render_kernel.render_numpy`; both give the same arrays bit for bit.
    """
    args = (camera, centers, axes, radii, part, n_parts, rays, outer_only, buried_by)
    out = render_kernel.render_compiled(*args)
    return PartRender(*(render_kernel.render_numpy(*args) if out is None else out))


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
    return render_kernel.ray_grid(camera)
