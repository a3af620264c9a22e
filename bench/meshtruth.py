"""Closest points on a triangle mesh and barycentric material points (benchmark truth)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def closest_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray):
    """Closest points of p (N, 3) on triangles (a, b, c) (N, 3 each) -> (point, bary (N, 3)).

    Ericson, Real-Time Collision Detection, 5.1.5, vectorised.
    """
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.einsum("ni,ni->n", ab, ap), np.einsum("ni,ni->n", ac, ap)
    bp = p - b
    d3, d4 = np.einsum("ni,ni->n", ab, bp), np.einsum("ni,ni->n", ac, bp)
    cp = p - c
    d5, d6 = np.einsum("ni,ni->n", ab, cp), np.einsum("ni,ni->n", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        den = va + vb + vc
        v = vb / den
        w = vc / den
        bary = np.stack([1 - v - w, v, w], axis=1)
        # Edge and vertex regions.
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
    cases = [
        ((d1 <= 0) & (d2 <= 0), np.stack([np.ones_like(d1), 0 * d1, 0 * d1], 1)),
        ((d3 >= 0) & (d4 <= d3), np.stack([0 * d1, np.ones_like(d1), 0 * d1], 1)),
        ((d6 >= 0) & (d5 <= d6), np.stack([0 * d1, 0 * d1, np.ones_like(d1)], 1)),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), np.stack([1 - t_ab, t_ab, 0 * d1], 1)),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), np.stack([1 - t_ac, 0 * d1, t_ac], 1)),
        ((va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0), np.stack([0 * d1, 1 - t_bc, t_bc], 1)),
    ]
    done = np.zeros(len(p), bool)
    for mask, bc in cases:
        m = mask & ~done
        bary[m] = bc[m]
        done |= m
    q = bary[:, :1] * a + bary[:, 1:2] * b + bary[:, 2:] * c
    return q, bary


def nearest_on_mesh(xyz: np.ndarray, vertices: np.ndarray, faces: np.ndarray, k: int = 16):
    """Nearest surface points of xyz (N, 3): (distance (N,), face (N,), bary (N, 3))."""
    tri = vertices[faces]  # (T, 3, 3)
    cent = tri.mean(axis=1)
    _, cand = cKDTree(cent).query(xyz, k=k)
    n = len(xyz)
    best = np.full(n, np.inf)
    face = np.zeros(n, int)
    bary = np.zeros((n, 3))
    for j in range(k):  # loop over candidates, not points
        f = cand[:, j]
        q, bc = closest_on_triangles(xyz, tri[f, 0], tri[f, 1], tri[f, 2])
        d = np.linalg.norm(q - xyz, axis=1)
        better = d < best
        best[better], face[better], bary[better] = d[better], f[better], bc[better]
    return best, face, bary
