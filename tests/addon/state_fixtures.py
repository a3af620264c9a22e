"""Seeded synthetic fitted states for the add-on tests (no files needed)."""

from __future__ import annotations

import numpy as np

from core.metaballs import make_metaballs
from core.skeleton import make_skeleton
from core.state import FitState, Quality


def synthetic_state(n_frames: int = 12, seed: int = 7, amplitude: float = 0.4) -> FitState:
    """A walking-ish random motion: smooth joint angles within ±amplitude rad, a root
    path moving 1 m along −Y, per-subject scales within ±10 %."""
    rng = np.random.default_rng(seed)
    skel = make_skeleton()
    s = rng.uniform(0.9, 1.1, skel.n_groups)
    t = np.linspace(0.0, 1.0, n_frames)[:, None]
    phase = rng.uniform(0, 2 * np.pi, skel.n_dof)
    freq = rng.uniform(0.5, 2.0, skel.n_dof)
    theta = amplitude * np.sin(2 * np.pi * freq * t + phase)
    theta = np.clip(theta, skel.dof_lo, skel.dof_hi)
    root = np.column_stack([0.1 * np.sin(3 * t[:, 0]), -t[:, 0], 0.95 + 0.02 * t[:, 0]])
    balls = make_metaballs(skel, "simplified", s)
    return FitState(
        skeleton=skel,
        s=s,
        metaballs=balls,
        root_xyz=root,
        theta=theta,
        quality=Quality.empty(n_frames, skel.n_dof),
        fps=25.0,
        source_scene="synthetic",
    )
