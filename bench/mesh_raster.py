"""Exact z-buffered rasterisation of a triangle mesh at pixel centres, batched in numpy.

The visibility-index reference (:mod:`bench.visibility`) needs, for every labelled
region of the true mesh, the pixels it covers ignoring occlusion and the pixels where
it is the front-most surface — with the same sampling as our ellipsoid renderer
(:func:`core.model_render.render_parts`), which casts one ray through each pixel
centre.  Splatting random surface points instead rounds every sample to its nearest
pixel: a pixel counts as soon as any sample of the part falls within half a pixel of
its centre, which dilates each part's area by a band of up to half a pixel along its
outline and does not converge to the pixel-centre coverage as the sample count grows
(on walk_line3, |ΔVI| 0.077 / 0.084 / 0.087 with 8 / 32 / 96 samples per triangle).
Here every triangle is tested against the pixel centres inside its projected bounding
box, grouped by box size so the work stays in a few array operations per camera.

Frames: pixel centres at integer ``(u, v)`` as in :mod:`core.camera`; depth is the
camera-frame z, interpolated perspective-correctly (1/z linear in the image).
"""

from __future__ import annotations

import numpy as np


def rasterize(camera, vertices: np.ndarray, faces: np.ndarray):
    """Fragments of a mesh: every (pixel centre, triangle) pair the triangle covers.

    Parameters
    ----------
    camera : core.camera.Camera
    vertices : ndarray, shape (V, 3)
        World positions, metres.
    faces : ndarray, shape (T, 3), int
        Vertex indices of each triangle.

    Returns
    -------
    pix : ndarray, shape (N,), int
        Flat pixel index ``v * width + u`` of each fragment.
    depth : ndarray, shape (N,)
        Camera-frame depth of the surface at that pixel centre, metres.
    tri : ndarray, shape (N,), int
        Triangle of each fragment.
    bary : ndarray, shape (N, 3)
        Barycentric coordinates of the pixel centre in its triangle.
    """
    w, h = camera.size
    vertices = np.asarray(vertices, float)
    faces = np.asarray(faces, int)
    uv = camera.project(vertices)
    z = camera.to_camera(vertices)[:, 2]
    t_uv, t_z = uv[faces], z[faces]  # (T, 3, 2), (T, 3)
    ok = np.all(np.isfinite(t_uv), axis=(1, 2)) & np.all(t_z > 1e-6, axis=1)
    lo = np.ceil(np.where(ok[:, None], t_uv.min(axis=1), 0.0)).astype(np.int64)
    hi = np.floor(np.where(ok[:, None], t_uv.max(axis=1), -1.0)).astype(np.int64)
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, [w - 1, h - 1])
    span = hi - lo + 1  # (T, 2)
    ok &= np.all(span > 0, axis=1)
    a, b, c = t_uv[:, 0], t_uv[:, 1], t_uv[:, 2]
    area = _cross(b - a, c - a)
    ok &= np.abs(area) > 1e-12
    size = span.max(axis=1)
    out = ([], [], [], [])
    lim = 1
    while ok.any():
        sel = np.flatnonzero(ok & (size <= lim))
        ok[sel] = False
        if len(sel):
            oy, ox = np.divmod(np.arange(lim * lim), lim)
            px = lo[sel, 0, None] + ox[None]  # (n, lim²)
            py = lo[sel, 1, None] + oy[None]
            inbox = (px <= hi[sel, 0, None]) & (py <= hi[sel, 1, None])
            p = np.stack([px, py], axis=-1).astype(float)
            wb = _cross(p - a[sel, None], (c - a)[sel, None]) / area[sel, None]
            wc = _cross((b - a)[sel, None], p - a[sel, None]) / area[sel, None]
            wa = 1.0 - wb - wc
            inside = inbox & (wa >= -1e-9) & (wb >= -1e-9) & (wc >= -1e-9)
            ti, k = np.nonzero(inside)
            bary = np.stack([wa[ti, k], wb[ti, k], wc[ti, k]], axis=1)
            t = sel[ti]
            invz = np.einsum("nk,nk->n", bary, 1.0 / t_z[t])
            out[0].append(py[ti, k] * w + px[ti, k])
            out[1].append(1.0 / invz)
            out[2].append(t)
            out[3].append(bary)
        lim *= 2
    if not out[0]:
        return np.zeros(0, int), np.zeros(0), np.zeros(0, int), np.zeros((0, 3))
    return tuple(np.concatenate(x) for x in out)


def _cross(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """z component of the 2-D cross product of (..., 2) arrays."""
    return p[..., 0] * q[..., 1] - p[..., 1] * q[..., 0]


def part_visibility(pix: np.ndarray, depth: np.ndarray, part: np.ndarray, n_parts: int):
    """Visibility index (P,) and full areas (P,) from labelled fragments.

    ``full[k]``: distinct pixels with a fragment of part k (occlusion ignored);
    visible: pixels whose nearest fragment is of part k; VI = visible / full (NaN where
    full is 0).
    """
    full = np.array([np.unique(pix[part == k]).size for k in range(n_parts)])
    order = np.lexsort((depth, pix))
    first = np.ones(len(order), bool)
    first[1:] = pix[order][1:] != pix[order][:-1]
    visible = np.bincount(part[order][first], minlength=n_parts)[:n_parts]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(full > 0, visible / full, np.nan), full
