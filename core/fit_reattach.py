"""Seen parts below a filled hidden part: re-posed to stay where their points put them.

The sequence fit's last step (:func:`core.fit_coupling.fill_unobserved`) replaces the
angles of hidden parts.  Coupling and bridging touch only angles every one of whose
descendants is hidden; mirroring (:func:`core.fit_mirror.mirror_hidden`) replaces the
angles of every hidden part of an arm, also above a part that was seen — an upper arm
hidden behind the trunk carrying a forearm and hand that the cameras see.  The seen
part's own angles were fitted to its points *under the upper arm the sequential pass
held*; rotating that upper arm afterwards swings the seen forearm and hand off the
points they were fitted to.

:func:`reattach_seen` undoes that swing: in each frame where a replaced angle has a
seen descendant, the seen descendants' angles are solved (Gauss–Newton on the analytic
joint Jacobians, within the joint limits) so that the joints they move lie where the
fit had put them before the replacement.  The replaced angles stay as they are; only
the seen parts' own angles change, and only where their parent was replaced.

On jumps_line3 (CMU 01_01, line3; run 0 of ``bench.fit_spread``, in-process on the
fill step's inputs) the right arm is behind the body in every frame and mirrored from
the left; at the tracker's regrowth at frame 42 its forearm and hand get 123 points,
fitted under the held upper arm.  Mirroring the upper arm had put the seen wrist
89 → 123 mm off in frames 42–45; re-posed 41–48 mm, MPJPE 15.14 → 14.72 mm.
"""

from __future__ import annotations

import numpy as np

from .skeleton import Skeleton, joint_jacobians


def descendant_dofs(skel: Skeleton) -> np.ndarray:
    """(n, n) bool: ``out[k, j]`` when DOF j lies below DOF k in the chain (j ≠ k); the
    transpose of :meth:`Skeleton.ancestors` without the diagonal."""
    return skel.ancestors().T & ~np.eye(skel.n_dof, dtype=bool)


def reattach_seen(
    skel: Skeleton,
    before: np.ndarray,
    after: np.ndarray,
    root_xyz: np.ndarray,
    s: np.ndarray,
    replaced: np.ndarray,
    hidden: np.ndarray,
    diverged: np.ndarray | None = None,
    iterations: int = 20,
    damping: float = 1e-4,
    tol: float = 1e-8,
) -> tuple[np.ndarray, np.ndarray]:
    """Re-pose the seen parts below replaced angles (see the module text).

    Parameters
    ----------
    before : (F, n) radians, the fitted angles before the replacement
    after : (F, n) radians, the angles with the hidden ones replaced
    root_xyz : (F, 3) metres; s : (G,) bone scales
    replaced : (F, n) bool, the angles that were replaced
    hidden : (F, n) bool, angles of parts without observations of their own (a seen
        descendant is one that is neither hidden nor replaced)
    diverged : (F,) bool, frames left as they are
    iterations, damping, tol : Gauss–Newton steps per frame, the Levenberg damping of
        the normal matrix (its diagonal scale, m²/rad²) and the step (radians) below
        which it stops

    Returns
    -------
    theta : (F, n) a copy of ``after`` with the seen descendants re-posed
    moved : (F, n) bool, the angles changed here
    """
    before = np.asarray(before, float)
    theta = np.array(after, float)
    replaced = np.asarray(replaced, bool)
    hidden = np.asarray(hidden, bool)
    nf = len(theta)
    div = np.zeros(nf, bool) if diverged is None else np.asarray(diverged, bool)
    below = descendant_dofs(skel)
    moved = np.zeros(theta.shape, bool)
    lo, hi = np.asarray(skel.dof_lo, float), np.asarray(skel.dof_hi, float)
    for f in np.flatnonzero(replaced.any(axis=1) & ~div):
        free = below[replaced[f]].any(axis=0) & ~hidden[f] & ~replaced[f]
        if not free.any():
            continue
        idx = np.flatnonzero(free)
        x0, J0, _ = joint_jacobians(skel, before[f][None], root_xyz[f][None], s)
        # the joints these angles move, kept where the fit had them
        keep = np.abs(J0[0][:, :, idx]).sum(axis=(1, 2)) > 0.0
        target = x0[0][keep]
        q = theta[f].copy()
        for _ in range(iterations):
            x, J, _ = joint_jacobians(skel, q[None], root_xyz[f][None], s)
            r = (x[0][keep] - target).reshape(-1)
            A = J[0][keep][:, :, idx].reshape(-1, len(idx))
            H = A.T @ A
            H[np.diag_indices_from(H)] += damping
            step = -np.linalg.solve(H, A.T @ r)
            q[idx] = np.clip(q[idx] + step, lo[idx], hi[idx])
            if np.abs(step).max() < tol:
                break
        moved[f, idx] = q[idx] != theta[f, idx]
        theta[f] = q
    return theta, moved
