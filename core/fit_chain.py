"""A prior that neighbouring spine links move alike.

The trunk is a chain of three links above the pelvis (``lowerback``, ``spine``,
``chest``), each with three single-DOF joints.  Their sum is what the surface sees: a
twist of the lower back undone by an opposite twist of the spine, or a bend of one link
undone by its neighbours, changes the trunk's outline very little.  Each per-frame fit
can then move a little along such a null direction, and over a take the links
counter-rotate far from any posture a person takes.  On make demo's walk with the
clicks moved by 0.5 px (``bench.fit_spread`` run 1) the lower back twisted −40° under a
spine twisted +42° by frame 45, the spine bent 25° more than at the clicked frame, and
the head, carried along, was 80 mm off in frames 34–39.  In the truth the lower back and
the spine twist together within 3°.

:func:`chain_prior` ties each link's change from the clicked posture to its neighbour's,
per axis: ``((θ_a − θ_a⁰) − (θ_b − θ_b⁰)) / σ`` for consecutive links a, b.  A bend or
twist shared along the chain costs nothing; only the split among the links does.
Off by default (``SequenceSettings.sigma_trunk_chain`` None): at σ 0.1 rad make demo's
walk over four click sets has median MPJPE 15.6 mm against 16.5 (run 1: 16.25 → 14.90,
the head 15.6 → 4.4 mm), jumps_line3 15.4 against 15.0, but dance_line3 is lost from
frame 5 (298 mm, 27 frames diverged, against 76 mm and 14); ``docs/design.md``.

Arrays: ``theta0`` (n,) radians, the clicked posture.
"""

from __future__ import annotations

import numpy as np

from .skeleton import Skeleton

#: Consecutive links whose changes the prior ties together, lowest first.
TRUNK_CHAIN = ("lowerback", "spine", "chest")


def chain_prior(
    skel: Skeleton,
    theta0: np.ndarray,
    sigma: float,
    chain: tuple = TRUNK_CHAIN,
    axes: str = "xyz",
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted linear prior ``(A, b)`` tying neighbouring links' changes together.

    Parameters
    ----------
    skel : the skeleton (its DOFs named ``<link>_<axis>``)
    theta0 : (n,) the reference posture (the clicked frame's), radians
    sigma : σ (radians) of the difference of two neighbours' changes
    chain : link names in order; a pair whose DOF for an axis is missing is skipped
    axes : the axes tied

    Returns
    -------
    A : (P, n) and b : (P,), such that the residuals are ``A θ − b`` (already divided
    by σ); P = 0 when the skeleton has no such pair.
    """
    theta0 = np.asarray(theta0, float)
    names = list(skel.dof_names)
    rows = []
    for a, b in zip(chain[:-1], chain[1:], strict=True):
        for ax in axes:
            da, db = f"{a}_{ax}", f"{b}_{ax}"
            if da in names and db in names:
                row = np.zeros(skel.n_dof)
                row[names.index(da)], row[names.index(db)] = 1.0, -1.0
                rows.append(row)
    A = np.array(rows).reshape(-1, skel.n_dof) / sigma
    return A, A @ theta0
