"""Held angles: a running median over time where nothing observes a part.

The sequence fit's last step (:func:`core.fit_coupling.fill_unobserved`) couples,
mirrors or bridges the angles of unobserved parts where it can.  What it leaves —
a stretch that runs to the first or last frame, a limb neither coupled nor mirrored
— keeps the values of the sequential pass: the damped prediction pulled, frame by
frame, by the weak terms that reach a part without points (the prior, the contours,
the silhouette containment; which of them moves it was not traced).  No observation
decides those values, and they flicker: on jumps_line3 the right leg, behind the left in all
three cameras from frame 3, swings its hip's abduction between −2° and −9° from one
frame to the next (frames 27–33), its ankle 25 ↔ 97 mm from the truth.

:func:`smooth_held` replaces each such angle, within each unbroken stretch, by its
running median over ``width`` frames (edges: the nearest value repeated), which keeps
a held value or a slow drift and drops one-frame excursions.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import median_filter

from .fit_bridge import hidden_runs


def smooth_held(
    theta: np.ndarray, held: np.ndarray, diverged: np.ndarray | None = None, width: int = 7
) -> tuple[np.ndarray, np.ndarray]:
    """Running median of the held angles over time (see the module text).

    Parameters
    ----------
    theta : (F, n) radians
    held : (F, n) bool, the angles no observation decides and no filling replaced
    diverged : (F,) bool, frames that break a stretch (left as they are)
    width : frames in the median's window (odd; 1 or less: nothing done)

    Returns
    -------
    theta : (F, n) a copy with the held stretches smoothed
    smoothed : (F, n) bool, the angles whose value changed
    """
    out = np.array(theta, float)
    held = np.asarray(held, bool)
    if diverged is not None:
        held = held & ~np.asarray(diverged, bool)[:, None]
    if width <= 1:
        return out, np.zeros(out.shape, bool)
    for k in np.flatnonzero(held.any(axis=0)):
        for a, b in hidden_runs(held[:, k]):
            if b - a >= 3:
                out[a:b, k] = median_filter(out[a:b, k], size=int(width), mode="nearest")
    return out, out != np.asarray(theta, float)
