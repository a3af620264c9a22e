"""Active per-part camera selection (the second paper, sec. 4).

A body part is observed in a camera only when it is visible there (visibility index
``VI >= 0.2``) and the camera observes its motion: cameras are ranked by
``|sum_j dx_j|``, the image displacement of the part's occluding-contour points under
the predicted motion (eq. 7–9).  We keep, among the visible cameras, those whose
observability reaches ``keep_ratio`` of the best one, so a camera looking along the
motion (a degenerate view) is left out while equally good views are fused.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Selection:
    """Which cameras each part uses in one frame.

    Attributes
    ----------
    use : ndarray, shape (P, C), bool
    visibility : ndarray, shape (P, C)
        Visibility index (NaN: outside the image).
    observability : ndarray, shape (P, C)
        ``|sum of predicted contour displacements|``, pixels.
    rank : ndarray, shape (P, C), int
        0 for the best camera of a part, -1 for cameras not visible.
    """

    use: np.ndarray
    visibility: np.ndarray
    observability: np.ndarray
    rank: np.ndarray

    def cameras_of(self, part: int) -> np.ndarray:
        return np.flatnonzero(self.use[part])


def observability(displacements: list[list[np.ndarray]]) -> np.ndarray:
    """``|sum_j dx_j|`` per part and camera.

    Parameters
    ----------
    displacements : list (P) of list (C) of ndarray (n, 2)
        Predicted image displacement of each contour point of part p in camera c.

    Returns
    -------
    ndarray, shape (P, C), pixels
    """
    P, C = len(displacements), len(displacements[0]) if displacements else 0
    out = np.zeros((P, C))
    for p in range(P):
        for c in range(C):
            d = np.asarray(displacements[p][c]).reshape(-1, 2)
            out[p, c] = np.linalg.norm(d.sum(axis=0)) if len(d) else 0.0
    return out


def select_cameras(
    visibility: np.ndarray,
    observ: np.ndarray | None = None,
    min_visibility: float = 0.2,
    keep_ratio: float = 0.3,
    min_motion_px: float = 0.5,
) -> Selection:
    """Select the cameras of every part.

    Parameters
    ----------
    visibility : ndarray, shape (P, C)
        Visibility indices (NaN where the part projects outside the image).
    observ : ndarray, shape (P, C), optional
        Observability (see :func:`observability`); when None or when the best camera
        sees less than ``min_motion_px`` of motion (the part is still), every visible
        camera is used.
    """
    vis = np.nan_to_num(np.asarray(visibility, float), nan=0.0)
    visible = vis >= min_visibility
    P, C = vis.shape
    obs = np.zeros((P, C)) if observ is None else np.asarray(observ, float)
    use = visible.copy()
    rank = np.full((P, C), -1, int)
    for p in range(P):
        cams = np.flatnonzero(visible[p])
        if len(cams) == 0:
            continue
        order = cams[np.argsort(-obs[p, cams], kind="stable")]
        rank[p, order] = np.arange(len(order))
        best = obs[p, order[0]]
        if observ is not None and best >= min_motion_px:
            use[p] = False
            use[p, order[obs[p, order] >= keep_ratio * best]] = True
    return Selection(use, np.asarray(visibility, float), obs, rank)
