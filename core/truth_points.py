"""Truth-derived 3-D observations: a development stand-in for the tracker's points.

**Not** the pipeline's measurement: these points come from the synthetic scene's
true mesh (``truth.npz`` ``vertices`` and ``faces``), so results computed from them
say how well the body model and the fitter do *given* surface points of a tracker's
quality, not what the image pipeline achieves.  Benchmarks label them
"truth-derived observations".

Per frame: random points on the mesh surface (faces chosen by area, uniform
barycentric coordinates); a point is kept when at least ``min_views`` cameras see it
— inside the image and not hidden by the body, judged by a point z-buffer of the
mesh's vertices and face centres in cells of ``cell_px`` pixels with a depth
tolerance ``depth_tol`` metres; then Gaussian noise of ``noise_m`` per coordinate and
a share ``outliers`` of gross errors (5–20 cm in a random direction).
"""

from __future__ import annotations

import numpy as np

from .camera import Camera


def _visible(cam: Camera, pts: np.ndarray, occ: np.ndarray, cell_px: float,
             depth_tol: float) -> np.ndarray:
    """(N,) bool: ``pts`` in front of the occluders ``occ`` (M, 3) in ``cam``'s image."""
    w, h = cam.size
    both = np.concatenate([occ, pts])
    with np.errstate(all="ignore"):
        uv = cam.project(both)
    z = cam.to_camera(both)[:, 2]
    nx, ny = int(np.ceil(w / cell_px)), int(np.ceil(h / cell_px))
    inside = (np.all(np.isfinite(uv), axis=1) & (z > 0) & (uv[:, 0] >= -0.5)
              & (uv[:, 1] >= -0.5) & (uv[:, 0] < w - 0.5) & (uv[:, 1] < h - 0.5))
    cell = np.full(len(both), -1)
    cu = np.clip(((uv[inside, 0] + 0.5) / cell_px).astype(int), 0, nx - 1)
    cv = np.clip(((uv[inside, 1] + 0.5) / cell_px).astype(int), 0, ny - 1)
    cell[inside] = cv * nx + cu
    zbuf = np.full(nx * ny, np.inf)
    np.minimum.at(zbuf, cell[inside], z[inside])
    p_cell, p_z, p_in = cell[len(occ):], z[len(occ):], inside[len(occ):]
    return p_in & (p_z <= zbuf[np.maximum(p_cell, 0)] + depth_tol)


def sample_frame(vertices: np.ndarray, faces: np.ndarray, cameras: list[Camera],
                 n_points: int, rng: np.random.Generator, noise_m: float = 0.0015,
                 outliers: float = 0.05, min_views: int = 2, cell_px: float = 3.0,
                 depth_tol: float = 0.015) -> tuple[np.ndarray, np.ndarray]:
    """Noisy visible surface points of one frame.

    Parameters
    ----------
    vertices : (V, 3) world metres; faces : (T, 3) int
    cameras : the scene's cameras
    n_points : candidate points drawn on the surface (the visible ones are kept)

    Returns
    -------
    xyz : (N, 3) world metres, noisy, with outliers
    is_outlier : (N,) bool
    """
    v = np.asarray(vertices, float)
    tri = v[faces]  # (T, 3, 3)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    t = rng.choice(len(faces), n_points, p=area / area.sum())
    a, b = rng.random((2, n_points))
    flip = a + b > 1
    a[flip], b[flip] = 1 - a[flip], 1 - b[flip]
    pts = tri[t, 0] + a[:, None] * (tri[t, 1] - tri[t, 0]) + b[:, None] * (tri[t, 2] - tri[t, 0])
    occ = np.concatenate([v, tri.mean(axis=1)])
    views = np.zeros(n_points, int)
    for cam in cameras:
        views += _visible(cam, pts, occ, cell_px, depth_tol)
    xyz = pts[views >= min_views]
    xyz = xyz + rng.normal(0.0, noise_m, xyz.shape)
    bad = rng.random(len(xyz)) < outliers
    d = rng.normal(size=(int(bad.sum()), 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    xyz[bad] += d * rng.uniform(0.05, 0.20, (len(d), 1))
    return xyz, bad


def truth_observations(truth: dict, cameras: list[Camera], n_points: int = 3000,
                       seed: int = 0, frames: range | None = None, **kwargs) -> list:
    """Truth-derived observations of every frame (see the module docstring).

    Returns
    -------
    list of :class:`core.fit.FramePoints` (``sigma`` = the noise level, no ids).
    """
    from .fit import FramePoints

    rng = np.random.default_rng(seed)
    verts, faces = truth["vertices"], np.asarray(truth["faces"], int)
    frames = range(len(verts)) if frames is None else frames
    noise = float(kwargs.get("noise_m", 0.0015))
    out = []
    for f in frames:
        xyz, _ = sample_frame(verts[f], faces, cameras, n_points, rng, **kwargs)
        out.append(FramePoints(xyz=xyz, sigma=np.full(len(xyz), max(noise, 1e-4))))
    return out
