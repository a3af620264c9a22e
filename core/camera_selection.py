"""Active per-part camera selection (the second paper, sec. 4).

A body part is observed in a camera only when it is visible there (visibility index
``VI >= 0.2``) and the camera observes its motion: cameras are ranked by
``|sum_j dx_j|``, the image displacement of the part's occluding-contour points under
the predicted motion (eq. 7–9).  We keep, among the visible cameras, those whose
observability reaches ``keep_ratio`` of the best one, so a camera looking along the
motion (a degenerate view) is left out while equally good views are fused.
:func:`add_wide_views` goes past the paper: a part left with views that all look at it
along nearly one line also gets a camera across them, which fixes where it lies along
those lines.
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


def add_wide_views(
    sel: Selection,
    eyes: np.ndarray,
    part_xyz: np.ndarray,
    max_spread_deg: float,
    wide_deg: float,
    min_visibility: float = 0.2,
    pairable: np.ndarray | None = None,
    outline: np.ndarray | None = None,
    min_outline: int = 0,
) -> None:
    """Give a part whose selected views all look at it along nearly one line one more
    camera across them (``sel.use``, in place).

    The ranking keeps the views that see a limb swing, and can drop the one that sees
    where it lies across them.  A part whose selected views' lines of sight lie within
    ``max_spread_deg`` of each other also uses one visible camera at least ``wide_deg``
    across every one of them: of those, the one that sees most of the part's predicted
    motion (``sel.observability``), then the most across.  Angles are between lines: a
    camera facing another across the part sees the same outline.

    Parameters
    ----------
    sel : Selection (P parts, C cameras)
    eyes : ndarray, shape (C, 3)
        Projection centres, world metres.
    part_xyz : ndarray, shape (P, 3)
        A point of each part (its metaballs' mean centre), world metres; NaN: no part.
    pairable : ndarray, shape (C,), bool, optional
        Cameras with image contours to pair (default: all).
    outline : ndarray, shape (P, C), optional
        The part's rim points on the body's outline in each camera.  With it, a selected
        view counts only where it shows at least ``min_outline`` of them (an arm seen
        inside the trunk's outline has no occluding contour), and only such a camera is
        added.
    """
    C = len(eyes)
    pairable = np.ones(C, bool) if pairable is None else np.asarray(pairable, bool)
    visible = (np.nan_to_num(sel.visibility, nan=0.0) >= min_visibility) & pairable
    outline = None if outline is None else np.asarray(outline)
    for p in np.flatnonzero(sel.use.any(axis=1) & np.isfinite(part_xyz).all(axis=1)):
        ray = part_xyz[p] - eyes
        ray /= np.linalg.norm(ray, axis=1, keepdims=True)
        used = np.flatnonzero(sel.use[p])
        free = np.flatnonzero(visible[p] & ~sel.use[p])
        if outline is not None:  # the views that show the part's outline, if any
            shown = used[outline[p, used] >= min_outline]
            used = shown if len(shown) else used
            free = free[outline[p, free] >= min_outline]
        if not len(free) or _line_deg(ray[used], ray[used].T).max() > max_spread_deg:
            continue
        wide = [(sel.observability[p, c], _line_deg(ray[used], ray[c]).min(), c) for c in free]
        wide = [w for w in wide if w[1] >= wide_deg]
        if wide:  # the best ranked, then the most across
            sel.use[p, max(wide)[2]] = True


def _line_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles (degrees) between the lines along unit vectors ``a @ b``."""
    return np.degrees(np.arccos(np.clip(np.abs(a @ b), 0.0, 1.0)))
