"""The whole-body shape of a sequence fit's shape frames (``SequenceSettings.shape = "fit"``).

:func:`whole_body_shape` runs :func:`core.shape_fit.fit_shape` on the points of the
shape frames that :func:`core.fit.fit_sequence` fitted, their poses held, and reports it
as a :class:`core.fit_types.ShapeRecord`.  Lengths in metres, angles in radians.
"""

from __future__ import annotations

import time

import numpy as np

from .fit_types import FramePoints, ShapeRecord
from .metaballs import Metaballs
from .shape_fit import ShapeSettings, fit_shape
from .skeleton import Skeleton


def whole_body_shape(skel: Skeleton, template: Metaballs, s: np.ndarray, theta: np.ndarray,
                     root: np.ndarray, frames: list[FramePoints], use: list[int],
                     cameras: list | None, settings: ShapeSettings | None,
                     msgs: list, progress=None) -> tuple[Metaballs, np.ndarray, ShapeRecord]:
    """The whole-body shape of ``frames[use]`` at their held poses.

    Runs :func:`core.shape_fit.fit_shape` from the ``template`` metaballs (its prior)
    with the bone scales ``s`` (G,), the poses ``theta[use]`` (K, n) radians and
    ``root[use]`` (K, 3) metres, every point's σ the larger of its own and the shape
    fit's ``sigma_point`` (metres).  Appends its message to ``msgs``; with no usable
    frame the template is kept.  ``progress`` (a :class:`core.progress.Progress`,
    optional) is updated every round of the shape fit, and cancels it.

    Returns
    -------
    (metaballs, radii (M, 3) metres, :class:`ShapeRecord`)
    """
    sc = settings or ShapeSettings()
    t0 = time.perf_counter()
    use = np.asarray(use, int)
    if not len(use):
        msgs.append("whole-body shape fit: no fitted shape frame, the template is kept")
        rec = ShapeRecord(use, np.zeros(0, bool), np.zeros(0), False,
                          "no fitted shape frame", 0.0)
        return template.copy(), template.radii.copy(), rec
    sf = fit_shape(skel, template, s, theta[use], root[use], [frames[f].xyz for f in use],
                   cameras, sigma=[np.maximum(frames[f].sigma, sc.sigma_point) for f in use],
                   settings=sc,
                   progress=None if progress is None else
                   (lambda k, n: progress.update(k, n, "whole-body shape")))
    rec = ShapeRecord(use, sf.frame_ok.copy(), sf.rms_m.copy(), bool(sf.converged), sf.message,
                      time.perf_counter() - t0)
    rms = sf.rms_m[sf.frame_ok]
    msgs.append(f"whole-body shape fit of frames {use.tolist()}: {sf.message}"
                + (f" (surface RMS {1e3 * np.mean(rms):.2f} mm)" if len(rms) else ""))
    if not sf.frame_ok.any():
        return template.copy(), template.radii.copy(), rec
    return sf.metaballs, sf.metaballs.radii.copy(), rec
