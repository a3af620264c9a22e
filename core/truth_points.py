"""Truth-derived 3-D observations: a development stand-in for the tracker's points.

**Not** the pipeline's measurement: these points come from the synthetic scene's
true mesh (``truth.npz`` ``vertices`` and ``faces``), so results computed from them
say how well the body model and the fitter do *given* surface points of a tracker's
quality, not what the image pipeline achieves.  Benchmarks label them
"truth-derived observations".

Per frame: random points on the mesh surface (faces chosen by area, uniform
barycentric coordinates); a point is kept when at least ``min_views`` cameras see it.
A camera sees a point when the point is inside its image, its face turns towards the
camera at less than ``max_angle_deg`` from the face normal (a tracker cannot match a
surface seen edge-on), and nothing lies in front of it: the mesh is rasterised into a
per-pixel depth map (:func:`depth_map`) and the point's depth may exceed the map's at
its pixel by ``depth_tol`` metres plus the depth change across half a pixel diagonal
of its own face (which grows like ``tan`` of the viewing angle).  Then Gaussian noise
of ``noise_m`` per coordinate and a share ``outliers`` of gross errors (5–20 cm in a
random direction).

Before, visibility was judged by a z-buffer of vertex and face-centre samples in cells
of 3 px with a fixed 15 mm tolerance: a surface seen obliquely spans more than 15 mm
of depth within one cell, so about a third of the truly visible points were dropped —
most of them in rigs whose cameras see the body obliquely (``orthogonal3``).
"""

from __future__ import annotations

import numpy as np

from .camera import Camera


def _split(tri: np.ndarray) -> np.ndarray:
    """Midpoint subdivision (T, 3, 3) -> (4T, 3, 3)."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, bc, ca = 0.5 * (a + b), 0.5 * (b + c), 0.5 * (c + a)
    return np.concatenate(
        [np.stack(t, axis=1) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))]
    )


def depth_map(cam: Camera, tri: np.ndarray, window: int = 4) -> np.ndarray:
    """Depth (h, w) metres of the nearest triangle at every pixel centre (inf: none).

    Parameters
    ----------
    cam : Camera (distortion is applied to the vertices; triangles stay straight in
        the image, exact for small triangles)
    tri : (T, 3, 3) world triangles, metres
    window : triangles whose pixel bounding box exceeds ``window`` px are split until
        they fit (batched: every triangle tests the same ``window²`` pixel centres)

    Returns
    -------
    (h, w) float, camera-frame z of the nearest surface at each pixel centre.
    """
    w, h = (int(v) for v in cam.size)
    zbuf = np.full(h * w, np.inf)
    tri = np.asarray(tri, float)
    for _ in range(8):
        if not len(tri):
            break
        flat = tri.reshape(-1, 3)
        z = cam.to_camera(flat)[:, 2].reshape(-1, 3)
        front = np.all(z > 1e-6, axis=1)
        tri, z = tri[front], z[front]
        with np.errstate(all="ignore"):
            uv = cam.project(tri.reshape(-1, 3)).reshape(-1, 3, 2)
        lo = np.ceil(uv.min(axis=1))
        hi = np.floor(uv.max(axis=1))
        on = (
            np.all(np.isfinite(uv), axis=(1, 2))
            & np.all(hi >= 0, axis=1)
            & (hi[:, 0] >= 0)
            & (lo[:, 0] <= w - 1)
            & (lo[:, 1] <= h - 1)
        )
        big = on & np.any(hi - lo + 1 > window, axis=1)
        fit = on & ~big
        _raster(zbuf, w, h, uv[fit], z[fit], lo[fit], window)
        tri = _split(tri[big])
    return zbuf.reshape(h, w)


def _raster(zbuf, w, h, uv, z, lo, k):
    """Write triangles (their screen corners uv (T, 3, 2), depths z (T, 3)) whose
    pixel boxes start at ``lo`` (T, 2) and fit in k×k pixels into ``zbuf`` (h·w,)."""
    if not len(uv):
        return
    g = np.arange(k, dtype=float)
    px = lo[:, None, 0] + np.tile(g, k)[None]  # (T, k²)
    py = lo[:, None, 1] + np.repeat(g, k)[None]
    a, b, c = uv[:, 0], uv[:, 1], uv[:, 2]
    den = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
    ok = np.abs(den) > 1e-12
    den = np.where(ok, den, 1.0)[:, None]
    l1 = (
        (px - a[:, None, 0]) * (c[:, None, 1] - a[:, None, 1])
        - (c[:, None, 0] - a[:, None, 0]) * (py - a[:, None, 1])
    ) / den
    l2 = (
        (b[:, None, 0] - a[:, None, 0]) * (py - a[:, None, 1])
        - (px - a[:, None, 0]) * (b[:, None, 1] - a[:, None, 1])
    ) / den
    l0 = 1.0 - l1 - l2
    eps = -1e-9
    inside = ok[:, None] & (l0 >= eps) & (l1 >= eps) & (l2 >= eps)
    inside &= (px >= 0) & (px <= w - 1) & (py >= 0) & (py <= h - 1)
    depth = l0 * z[:, None, 0] + l1 * z[:, None, 1] + l2 * z[:, None, 2]
    cell = (py[inside] * w + px[inside]).astype(np.int64)
    np.minimum.at(zbuf, cell, depth[inside])


def visible(
    cam: Camera,
    pts: np.ndarray,
    normals: np.ndarray,
    zmap: np.ndarray,
    depth_tol: float = 0.005,
    max_angle_deg: float = 80.0,
) -> np.ndarray:
    """(N,) bool: surface points ``pts`` (N, 3) with unit face ``normals`` (N, 3), world,
    seen by ``cam`` given its depth map ``zmap`` (:func:`depth_map`)."""
    h, w = zmap.shape
    with np.errstate(all="ignore"):
        uv = cam.project(pts)
    z = cam.to_camera(pts)[:, 2]
    view = cam.center[None] - pts
    dist = np.linalg.norm(view, axis=1)
    cos = np.einsum("ij,ij->i", view, normals) / np.maximum(dist, 1e-12)
    cmin = np.cos(np.radians(max_angle_deg))
    iu = np.rint(uv[:, 0])
    iv = np.rint(uv[:, 1])
    inside = (
        np.all(np.isfinite(uv), axis=1)
        & (z > 0)
        & (iu >= 0)
        & (iv >= 0)
        & (iu <= w - 1)
        & (iv <= h - 1)
        & (cos > cmin)
    )
    zm = np.full(len(pts), -np.inf)
    zm[inside] = zmap[iv[inside].astype(int), iu[inside].astype(int)]
    px_m = z / cam.K[0, 0]  # metres per pixel at the point's depth
    tan = np.sqrt(np.maximum(1.0 - cos**2, 0.0)) / np.maximum(cos, cmin)
    tol = depth_tol + 0.75 * px_m * tan
    return inside & (z <= zm + tol)


def sample_frame(
    vertices: np.ndarray,
    faces: np.ndarray,
    cameras: list[Camera],
    n_points: int,
    rng: np.random.Generator,
    noise_m: float = 0.0015,
    outliers: float = 0.05,
    min_views: int = 2,
    depth_tol: float = 0.005,
    max_angle_deg: float = 80.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Noisy visible surface points of one frame.

    Parameters
    ----------
    vertices : (V, 3) world metres; faces : (T, 3) int, counter-clockwise seen from
        outside (outward normals)
    cameras : the scene's cameras
    n_points : candidate points drawn on the surface (the visible ones are kept)

    Returns
    -------
    xyz : (N, 3) world metres, noisy, with outliers
    is_outlier : (N,) bool
    """
    v = np.asarray(vertices, float)
    tri = v[faces]  # (T, 3, 3)
    nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area2 = np.linalg.norm(nrm, axis=1)
    t = rng.choice(len(faces), n_points, p=area2 / area2.sum())
    a, b = rng.random((2, n_points))
    flip = a + b > 1
    a[flip], b[flip] = 1 - a[flip], 1 - b[flip]
    pts = tri[t, 0] + a[:, None] * (tri[t, 1] - tri[t, 0]) + b[:, None] * (tri[t, 2] - tri[t, 0])
    nrm = nrm[t] / np.maximum(area2[t], 1e-300)[:, None]
    views = np.zeros(n_points, int)
    for cam in cameras:
        views += visible(cam, pts, nrm, depth_map(cam, tri), depth_tol, max_angle_deg)
    xyz = pts[views >= min_views]
    xyz = xyz + rng.normal(0.0, noise_m, xyz.shape)
    bad = rng.random(len(xyz)) < outliers
    d = rng.normal(size=(int(bad.sum()), 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    xyz[bad] += d * rng.uniform(0.05, 0.20, (len(d), 1))
    return xyz, bad


def truth_observations(
    truth: dict,
    cameras: list[Camera],
    n_points: int = 3000,
    seed: int = 0,
    frames: range | None = None,
    **kwargs,
) -> list:
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
