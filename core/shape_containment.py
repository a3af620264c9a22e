"""Metaball surfaces kept inside the foregrounds while the silhouettes shape the body.

The silhouette shape fit (:func:`core.contour_shape.fit_shape_to_contours`) pairs the
model's outer rim with the image contours nearby (12 px at most).  A metaball whose
rim stands further out than that, or whose rim is hidden behind another's in the
rendering that picks the rim, pays nothing for it: on pirouette_ortho3 two of the
head's three metaballs became discs that stand ~10 px out of every silhouette.  This
term samples points just inside each metaball's rendered surface and asks every camera
that sees them to find them in its foreground, as :func:`core.contour_obs.
containment_observations` does for the pose with points half-way in.

Frames: world Z up, metres; image pixels as in :mod:`core.camera`; metaball radii and
centres in their bones' frames, metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera import Camera, camera_project_jacobians
from .contour_obs import SilhouetteField, body_ellipsoids
from .metaballs import Metaballs
from .skeleton import Skeleton

#: Sample directions in a metaball's unit frame: the six axis ends and the eight
#: corners' directions, at ``depth`` of the rendered surface (a disc's rim is at its axis
#: ends, a slab's corners along the diagonals).
_DIRS = np.vstack(
    [np.eye(3), -np.eye(3), np.array(np.meshgrid(*[[-1, 1]] * 3)).reshape(3, -1).T / np.sqrt(3)]
)


@dataclass
class ShapeContainment:
    """Points of the metaballs outside a foreground, and their derivatives.

    Attributes
    ----------
    residual : ndarray, shape (M,)
        Distance of each point's projection outside the foreground beyond the
        tolerance, pixels (> 0: only points that count are returned).
    ball : ndarray, shape (M,), int
        The metaball the point belongs to.
    unit : ndarray, shape (M, 3)
        The point in its metaball's unit frame (semi-axes 1).
    grad : ndarray, shape (M, 3)
        The residual's gradient with respect to the point's world position, px / m.
    axis_grad : ndarray, shape (M, 3)
        The same along its metaball's three axes (world), px / m: the derivative by the
        k-th visible semi-axis is ``axis_grad[:, k] · unit[:, k]``.
    """

    residual: np.ndarray
    ball: np.ndarray
    unit: np.ndarray
    grad: np.ndarray
    axis_grad: np.ndarray

    def __len__(self) -> int:
        return len(self.residual)


def shape_containment(
    skel: Skeleton,
    theta: np.ndarray,
    root: np.ndarray,
    s: np.ndarray,
    balls: Metaballs,
    cameras: list[Camera],
    fields: list[SilhouetteField | None],
    tol_px: float = 3.0,
    depth: float = 0.9,
) -> ShapeContainment:
    """The points (:data:`_DIRS` at ``depth`` of each rendered ellipsoid's semi-axes)
    that project more than ``tol_px`` outside a camera's foreground.

    Parameters
    ----------
    theta : (n,) radians; root : (3,) metres; s : (G,) bone scales
    cameras : list (C) of Camera
    fields : list (C) of :class:`core.contour_obs.SilhouetteField` (None: a camera
        without a foreground, left out)

    A point that projects outside an image is left out for that camera.
    """
    centers, axes, radii, _ = body_ellipsoids(skel, theta, root, s, balls)
    E, K = len(radii), len(_DIRS)
    unit = np.broadcast_to(depth * _DIRS, (E, K, 3))
    xyz = (centers[:, None] + np.einsum("eij,ekj->eki", axes, unit * radii[:, None])).reshape(-1, 3)
    ball = np.repeat(np.arange(E), K)
    unit = unit.reshape(-1, 3)
    res, bl, un, gr = [], [], [], []
    for cam, fld in zip(cameras, fields, strict=True):
        if fld is None:
            continue
        uv, _, J_xyz = camera_project_jacobians(cam, xyz)
        d, g = fld.sample(uv)
        out = np.isfinite(d) & (d > tol_px)
        if not out.any():
            continue
        res.append(d[out] - tol_px)
        bl.append(ball[out])
        un.append(unit[out])
        gr.append(np.einsum("mi,mij->mj", g[out], J_xyz[out]))
    if not res:
        z = np.zeros((0, 3))
        return ShapeContainment(np.zeros(0), np.zeros(0, int), z, z, z)
    bl, gr = np.concatenate(bl), np.vstack(gr)
    return ShapeContainment(
        np.concatenate(res), bl, np.vstack(un), gr, np.einsum("mi,mik->mk", gr, axes[bl])
    )
