"""Free space in front of an observed point: no body lies between it and its cameras.

A surface point measured in a camera was *seen* there, so the line of sight from the
point to that camera's centre crosses no body.  The attractor equation alone (the point
on the surface ``Σ f = 0.5``) cannot tell the side of a part the point lies on: a
forearm whose points form a one-sided patch fits them equally well with its axis behind
the patch (right) or in front of it (the patch then on the forearm's far side, hidden
from every camera that measured it).  On the default scene the reappearing right
forearm was placed 9 cm in front of its own points in frames 25–34 (149 of its 151
points had body in their line of sight).

This module builds *probes*: for every point and every camera that measured it, points
a few centimetres along the line of sight (:func:`probes`).  A probe inside the body
(positive signed distance beyond a margin) is a visibility violation;
:func:`occlusion_cost` turns the probes' signed distances into a per-point cost on the
scale of :func:`core.fit_search.explain_cost`.

Arrays: ``xyz`` (N, 3) world metres; ``views`` (N, C) bool; ``centres`` (C, 3) world
metres; probes (N, K, 3) with K = C × len(depths).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Distances (metres) along the line of sight at which a point's probes sit: beyond the
#: tracker's depth noise (a few mm) and the model's shape error (~1 cm), within a limb's
#: thickness.
DEPTHS = (0.03, 0.06)


@dataclass
class Probes:
    """Probes of N points.

    Attributes
    ----------
    xyz : (N, K, 3) world metres — the probe positions
    valid : (N, K) bool — the probe's camera measured the point
    """

    xyz: np.ndarray
    valid: np.ndarray

    def __len__(self) -> int:
        return len(self.xyz)

    def select(self, keep) -> Probes:
        """The probes of the points ``keep`` (index or bool mask)."""
        return Probes(self.xyz[keep], self.valid[keep])


def probes(
    xyz: np.ndarray, views: np.ndarray, centres: np.ndarray, depths: tuple = DEPTHS
) -> Probes:
    """Probes along every point's lines of sight.

    Parameters
    ----------
    xyz : (N, 3) world points, metres
    views : (N, C) bool — camera c measured point i
    centres : (C, 3) camera centres, world metres
    depths : distances (metres) from the point towards the camera

    Returns
    -------
    Probes with K = C × len(depths), camera-major.
    """
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    views = np.asarray(views, bool).reshape(len(xyz), -1)
    centres = np.asarray(centres, float).reshape(-1, 3)
    if views.shape[1] != len(centres):
        raise ValueError(f"views has {views.shape[1]} cameras, centres {len(centres)}")
    u = centres[None] - xyz[:, None]  # (N, C, 3)
    u /= np.maximum(np.linalg.norm(u, axis=2, keepdims=True), 1e-12)
    t = np.asarray(depths, float)
    p = xyz[:, None, None] + u[:, :, None] * t[None, None, :, None]  # (N, C, T, 3)
    valid = np.repeat(views[:, :, None], len(t), axis=2)
    return Probes(p.reshape(len(xyz), -1, 3), valid.reshape(len(xyz), -1))


def occlusion_cost(
    d_probe: np.ndarray,
    valid: np.ndarray,
    margin: float = 0.01,
    tau: float = 0.05,
    sigma: float = 0.01,
) -> np.ndarray:
    """Per-point cost of body in the line of sight.

    Parameters
    ----------
    d_probe : (..., N, K) signed distance of every probe to the body surface, metres,
        positive inside
    valid : (N, K) bool
    margin : depth inside the body a probe may reach for free (shape error), metres
    tau, sigma : as :func:`core.fit_search.explain_cost`: a point costs at most
        ``(tau / sigma)²``

    Returns
    -------
    (..., N) ``min(max(max_k d_k − margin, 0), tau)² / sigma²`` over the valid probes
    """
    d = np.where(valid, np.asarray(d_probe, float), -np.inf).max(axis=-1)
    return np.minimum(np.maximum(d - margin, 0.0), tau) ** 2 / sigma**2


class FrameProbes:
    """Per-frame lines of sight for a sequence fit, the last frame's cached.

    Parameters
    ----------
    frames : sequence of objects with ``xyz`` (N, 3) and ``views`` ((N, C) bool or None)
    cameras : the C cameras (their ``center``), or None
    enabled : False gives None for every frame

    Calling it with a frame index gives that frame's :class:`Probes`, or None where the
    frame has no points, no views, or views for another number of cameras.
    """

    def __init__(self, frames, cameras, enabled: bool = True):
        self.frames = frames
        self.centres = None if cameras is None else np.array([c.center for c in cameras])
        self.enabled = enabled
        self._cache: dict = {}

    def __call__(self, f: int) -> Probes | None:
        pts = self.frames[f]
        if (
            not self.enabled
            or self.centres is None
            or pts.views is None
            or not len(pts.xyz)
            or pts.views.shape[1] != len(self.centres)
        ):
            return None
        if f not in self._cache:
            self._cache.clear()  # one frame at a time
            self._cache[f] = probes(pts.xyz, pts.views, self.centres)
        return self._cache[f]
