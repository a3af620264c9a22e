"""Two fits of one take, and the one the foregrounds explain better.

The sequence fit makes discrete choices (which camera a part uses, whether a limb
search's move is kept), so a small change in its input can send a hardly observed limb
down another path and lose it for the rest of the take.  Where the body is tracked from
its silhouettes and the texture flow alone (no 3-D points at the clicked frame: the
orthogonal rigs), :func:`core.fit_scene.run_scene` fits the take twice — with
Lucas–Kanade's corners and with corners refined by least squares matching
(``SequenceSettings.flow_choice``) — and keeps the fit whose body
disagrees with the foregrounds at fewer pixels over the take (:func:`choose`).  A lost
limb leaves its true foreground uncovered in every camera that sees it, frame after
frame; a fit that only differs by a few millimetres barely changes the count.

Frames: world Z up, metres; cameras as in :mod:`core.camera` (pixels, OpenCV frame).
"""

from __future__ import annotations

import numpy as np

from .silhouette_search import silhouette_disagreement
from .state import FitState


def foreground_disagreement(state: FitState, cameras: list, cframes: list) -> np.ndarray:
    """Pixels per frame where the state's body and the foregrounds disagree.

    Parameters
    ----------
    state : FitState
        A fitted take: its skeleton, bone scales, metaballs (the written, whole-body
        shape) and per-frame pose.
    cameras : list of Camera
        The scene's cameras, in the order of each contour frame's grids.
    cframes : list of ContourFrame or None, length >= ``state.n_frames``
        The take's contour frames (:func:`core.fit_contours.contour_frames`); their
        foreground grids (:meth:`core.fit_contours.ContourFrame.grids`) are what is
        counted.  A None entry counts nothing.

    Returns
    -------
    ndarray, shape (F,)
        Pixels, summed over the cameras, where either the body's projection (its
        ellipsoids, :func:`core.silhouette_search.silhouette_disagreement`) or the
        foreground covers what the other does not, on the grids' pixels (the
        foreground's bounding box and a margin).  A frame whose pose is not finite
        counts every foreground pixel, as a body that covers nothing would.
    """
    out = np.zeros(state.n_frames)
    for f in range(state.n_frames):
        cf = cframes[f]
        if cf is None:
            continue
        grids = cf.grids()
        if np.all(np.isfinite(state.theta[f])) and np.all(np.isfinite(state.root_xyz[f])):
            out[f] = silhouette_disagreement(
                state.skeleton,
                state.metaballs,
                state.theta[f],
                state.root_xyz[f],
                state.s,
                cameras,
                grids,
            )
        else:
            out[f] = float(sum(g.fg.sum() * g.step**2 for g in grids))
    return out


def choose(states: list[FitState], cameras: list, cframes: list) -> tuple[int, np.ndarray]:
    """The index of the state the foregrounds explain best, and each one's total.

    Fewer diverged frames win first; among those the smallest total of
    :func:`foreground_disagreement` over the take (ties: the first).

    Parameters
    ----------
    states : list of FitState
        Fits of the same take (the same frames, cameras and contour frames).
    cameras, cframes
        As for :func:`foreground_disagreement`.

    Returns
    -------
    best : int
    totals : ndarray, shape (len(states),)
        Each state's disagreement summed over its frames, pixels.
    """
    if not states:
        raise ValueError("no fitted states to choose from")
    totals = np.array([foreground_disagreement(s, cameras, cframes).sum() for s in states])
    diverged = np.array([int(np.sum(s.quality.diverged)) for s in states])
    order = np.lexsort((np.arange(len(states)), totals, diverged))
    return int(order[0]), totals
