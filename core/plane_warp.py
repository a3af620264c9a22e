"""The affine start of a match across a wide baseline, from the surface's tangent plane.

Least squares matching (:mod:`core.lsm`) estimates an affine warp between a template
patch and the search image, but Gauss–Newton only converges from a warp near the
true one.  Between two cameras 60–90° apart a surface patch is foreshortened
differently in each view, so the identity start fails.  Where the 3-D point and its
surface normal are known (a tracked point and its neighbours), the tangent plane
induces a homography between the views; its linearisation at the point is the affine
part the match should start from:

    A = ∂u_search / ∂u_template = J_search · ∂X/∂u_template,

``X`` the intersection of the template camera's viewing ray with the plane.  Computed
by finite steps of one pixel through :meth:`core.camera.Camera.rays` (lens distortion
included) and :meth:`core.camera.Camera.project`.

Frames: world metres; image pixels as in :mod:`core.camera`.
"""

from __future__ import annotations

import numpy as np

from .camera import Camera


def plane_affine(
    cam_template: Camera,
    cam_search: Camera,
    uv_template: np.ndarray,
    xyz: np.ndarray,
    normal: np.ndarray,
    step_px: float = 1.0,
    min_cos: float = 0.1,
) -> np.ndarray:
    """Affine parts (N, 2, 2) mapping template pixel offsets to search pixel offsets.

    Parameters
    ----------
    cam_template, cam_search : Camera
    uv_template : ndarray, shape (N, 2)
        Template centres, pixels.
    xyz : ndarray, shape (N, 3)
        The surface points, world metres (the plane passes through them).
    normal : ndarray, shape (N, 3)
        Unit surface normals, world.
    step_px : float
        Finite step in the template image, pixels.
    min_cos : float
        Below this |cos| between a template ray and the normal (a plane seen edge-on)
        the identity is returned for that point.

    Returns
    -------
    ndarray, shape (N, 2, 2)
        ``A`` with ``u_search − u0_search ≈ A (u_template − u0_template)``; the identity
        where the plane is seen edge-on or an input is not finite.
    """
    uv = np.asarray(uv_template, float).reshape(-1, 2)
    X0 = np.asarray(xyz, float).reshape(-1, 3)
    n = np.asarray(normal, float).reshape(-1, 3)
    out = np.tile(np.eye(2), (len(uv), 1, 1))
    if not len(uv):
        return out
    ok = np.all(np.isfinite(uv), 1) & np.all(np.isfinite(X0), 1) & np.all(np.isfinite(n), 1)
    hits = []
    for du in ((0.0, 0.0), (step_px, 0.0), (0.0, step_px)):
        o, d = cam_template.rays(np.where(ok[:, None], uv, 0.0) + du)
        nd = np.einsum("ni,ni->n", n, d)
        ok &= np.abs(nd) >= min_cos
        t = np.einsum("ni,ni->n", n, X0 - o) / np.where(ok, nd, 1.0)
        hits.append(o + t[:, None] * d)
    if not ok.any():
        return out
    p = [cam_search.project(h[ok]) for h in hits]
    out[ok] = np.stack([(p[1] - p[0]) / step_px, (p[2] - p[0]) / step_px], axis=-1)
    return out
