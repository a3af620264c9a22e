"""Surface looks and backgrounds as numpy images, and box-projected UVs (no bpy).

``sweater``: dense, high-contrast multi-scale noise (features of 1-8 mm on the body at
1 texel = 1 mm), which least squares matching can lock onto.  ``skin``: a smooth,
weak skin-tone variation (low contrast, only coarse features).
"""

from __future__ import annotations

import cv2
import numpy as np

LOOKS = ("sweater", "skin")

#: Metres of body surface per texture repeat (texture side).
TEXTURE_METRES = 1.0


def _octaves(rng: np.random.Generator, size: int, cells: list[int]) -> np.ndarray:
    """Sum of bicubically upsampled random grids, one per cell count, (size, size) in ~[-1, 1]."""
    out = np.zeros((size, size), np.float32)
    for c in cells:
        g = rng.standard_normal((c, c)).astype(np.float32)
        # Tile-able: wrap the grid before resizing so the texture repeats seamlessly.
        g = np.pad(g, 2, mode="wrap")
        up = cv2.resize(g, ((c + 4) * size // c,) * 2, interpolation=cv2.INTER_CUBIC)
        o = 2 * size // c
        out += up[o : o + size, o : o + size] / np.sqrt(len(cells))
    return out


def surface_texture(look: str, size: int = 1024, seed: int = 0) -> np.ndarray:
    """RGB texture ``(size, size, 3)`` float32 in [0, 1] for a surface look."""
    rng = np.random.default_rng(seed)
    if look == "sweater":
        n = _octaves(rng, size, [32, 64, 128, 256])
        hue = _octaves(rng, size, [8, 16])
        base = np.clip(0.5 + 0.32 * n, 0.02, 0.98)
        tint = np.stack([1.0 + 0.25 * hue, np.ones_like(hue), 1.0 - 0.25 * hue], axis=-1)
        return np.clip(base[..., None] * tint, 0.0, 1.0).astype(np.float32)
    if look == "skin":
        n = _octaves(rng, size, [4, 8, 16])
        skin = np.array([0.80, 0.60, 0.50], np.float32)
        return np.clip(skin * (1.0 + 0.05 * n[..., None]), 0.0, 1.0).astype(np.float32)
    raise ValueError(f"unknown look {look!r}; choose one of {LOOKS}")


def background_image(kind: str, size: tuple[int, int], seed: int = 0) -> np.ndarray:
    """Static background ``(H, W, 3)`` float32 in [0, 1]: ``plain`` grey or ``textured``."""
    w, h = size
    if kind == "plain":
        return np.full((h, w, 3), 0.45, np.float32)
    if kind == "textured":
        rng = np.random.default_rng(seed)
        side = int(2 ** np.ceil(np.log2(max(w, h, 64))))
        n = _octaves(rng, side, [8, 32, 128])[:h, :w]
        col = np.clip(0.4 + 0.2 * n, 0.0, 1.0)
        return np.stack([col * 0.9, col, col * 1.1], axis=-1).clip(0, 1).astype(np.float32)
    raise ValueError(f"unknown background {kind!r}; choose plain or textured")


def box_uvs(corner_xyz: np.ndarray, face_normals: np.ndarray, loop_face: np.ndarray) -> np.ndarray:
    """Per-loop UVs by box projection of the rest mesh.

    Each face is projected along the world axis closest to its normal; the three
    projections are offset in UV so that they show different parts of the texture.

    Parameters
    ----------
    corner_xyz : ndarray (L, 3)
        Rest position of each face corner (loop), metres.
    face_normals : ndarray (P, 3)
    loop_face : ndarray (L,) int
        Face index of each loop.

    Returns
    -------
    ndarray (L, 2) float32, in texture repeats (1 = :data:`TEXTURE_METRES`).
    """
    axis = np.argmax(np.abs(face_normals), axis=1)[loop_face]
    x, y, z = corner_xyz.T
    uv = np.where(
        (axis == 0)[:, None],
        np.stack([y, z], 1),
        np.where((axis == 1)[:, None], np.stack([x, z], 1), np.stack([x, y], 1)),
    )
    uv = uv / TEXTURE_METRES + np.array([0.0, 0.37, 0.71])[axis][:, None]
    return uv.astype(np.float32)
