"""Attractor observations as distances: the log field of a point's own part and neighbours.

Eq. 15 of the paper writes an attractor point ``x`` as ``Σ_{m ∈ part} f_m(x) = 0.5``.
Its residual in field units has a slope that varies by orders of magnitude with the
depth of the point (``f`` falls like ``exp(−2 d)``) and with the size of the
metaballs, so equal a-priori σ give unequal weights.  Here the residual is the
first-order signed distance of the *log* field:

    L(x) = ln Σ_{m ∈ members(x)} exp(−2 d_m(x)),     e(x) = (L(x) − ln 0.5) / |∇L(x)|

in metres (positive inside).  For a lone sphere of visible radius ``r0`` this is
``(r0² − r²)/(2 r)`` — the true distance near the surface, and still of the order of
the distance far inside or outside (where ``(F − 0.5)/|∇F|`` explodes).  ``L`` and its
derivatives are computed as a log-sum-exp (``p_m = softmax(−2 d_m)``), so a point far
from every member still has finite values.  ``1/|∇L|`` is held fixed within one
Gauss–Newton step (a weight, re-evaluated at every step), so the Jacobian is
``(∂L/∂params) / |∇L|``.

Membership is gathered, not masked: each point carries the indices ``idx`` (N, K) of
the metaballs of its part and of the adjacent parts (``valid`` (N, K) marks padding),
so every array is (N, K) with K ≈ 15 instead of (N, M) with M ≈ 90.

Arrays: ``x`` (N, 3) world metres; ``Rw`` (M, 3, 3), ``cw`` (M, 3) metaball world
frames; ``radii`` (M, 3) metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import attractor_kernel, field_kernel
from .metaballs import THRESHOLD, Metaballs
from .skeleton import Pose, Skeleton, bone_frames
from .vec3 import norm3, sum3

LN_T = float(np.log(THRESHOLD))


def member_table(skel: Skeleton, balls: Metaballs, members: str = "neighbours"):
    """Per-bone gather table of member metaballs.

    Parameters
    ----------
    members : ``"part"`` (the bone's own metaballs, eq. 15), ``"neighbours"`` (also its
        parent's and children's) or ``"body"`` (all)

    Returns
    -------
    table : (B, K) int metaball indices (padding repeats a valid index)
    valid : (B, K) bool
    """
    if members not in ("part", "neighbours", "body"):
        raise ValueError(f"unknown membership {members!r}")
    nb = len(skel.bone_names)
    adj = np.eye(nb, dtype=bool)
    if members == "body":
        adj[:] = True
    elif members == "neighbours":
        for b, p in enumerate(skel.bone_parent):
            if p >= 0:
                adj[b, p] = adj[p, b] = True
    lists = [np.nonzero(adj[b][balls.bone])[0] for b in range(nb)]
    k = max(max((len(v) for v in lists), default=1), 1)
    table = np.zeros((nb, k), dtype=int)
    valid = np.zeros((nb, k), dtype=bool)
    for b, v in enumerate(lists):
        if len(v):
            table[b, : len(v)] = v
            table[b, len(v) :] = v[0]
            valid[b, : len(v)] = True
    return table, valid


def gather(table: np.ndarray, valid: np.ndarray, part: np.ndarray):
    """``(idx (N, K), valid (N, K))`` of points with parts ``part`` (N,) (−1: none)."""
    part = np.asarray(part, dtype=int)
    p = np.clip(part, 0, len(table) - 1)
    return table[p], valid[p] & (part >= 0)[:, None]


@dataclass
class Attractor:
    """Log field of N points over their K member metaballs.

    Attributes
    ----------
    L : (N,) ``ln Σ f_m`` (−inf where a point has no member)
    grad : (N, 3) ``∇L``, 1/metre
    p : (N, K) softmax weights ``f_m / Σ f``
    y : (N, K, 3) the point in each member's frame, metres
    q : (N, K, 3) ``y / l²``
    gx : (N, K, 3) ``∇_x (−2 d_m)`` in world axes
    dist : (N,) signed distance ``(L − ln 0.5) / |∇L|``, metres, positive inside
    inv_g : (N,) ``1 / max(|∇L|, g_min)``, metres
    """

    L: np.ndarray
    grad: np.ndarray
    p: np.ndarray
    y: np.ndarray
    q: np.ndarray
    gx: np.ndarray
    dist: np.ndarray
    inv_g: np.ndarray


def attractor(
    x: np.ndarray,
    idx: np.ndarray,
    valid: np.ndarray,
    Rw: np.ndarray,
    cw: np.ndarray,
    radii: np.ndarray,
    g_min: float = 2.0,
) -> Attractor:
    """Log field, its gradient and the signed distance of points to their part's surface.

    Parameters
    ----------
    x : (N, 3); idx, valid : (N, K) from :func:`gather`
    g_min : floor of ``|∇L|`` (1/metre) in the distance (deep inside, ``∇L → 0``)
    """
    x = np.asarray(x, float)
    if field_kernel.enabled():
        N, K = idx.shape
        out = Attractor(
            L=np.empty(N),
            grad=np.empty((N, 3)),
            p=np.empty((N, K)),
            y=np.empty((N, K, 3)),
            q=np.empty((N, K, 3)),
            gx=np.empty((N, K, 3)),
            dist=np.empty(N),
            inv_g=np.empty(N),
        )
        if field_kernel.run(
            attractor_kernel.attractor_terms,
            np.ascontiguousarray(x),
            np.ascontiguousarray(idx, dtype=np.int64),
            np.ascontiguousarray(valid, dtype=np.bool_),
            np.ascontiguousarray(Rw, dtype=float),
            np.ascontiguousarray(cw, dtype=float),
            np.ascontiguousarray(radii, dtype=float),
            float(g_min),
            LN_T,
            out.L,
            out.grad,
            out.p,
            out.y,
            out.q,
            out.gx,
            out.dist,
            out.inv_g,
        ):
            return out
    R = Rw[idx]  # (N, K, 3, 3)
    y = np.matmul((x[:, None, :] - cw[idx])[..., None, :], R)[..., 0, :]  # Rᵀ (x − c)
    q = y / radii[idx] ** 2
    a = -2.0 * sum3(y * q)
    a = np.where(valid, a, -np.inf)
    top = a.max(axis=1)
    top_f = np.where(np.isfinite(top), top, 0.0)
    e = np.exp(a - top_f[:, None])
    tot = e.sum(axis=1)
    with np.errstate(divide="ignore"):
        L = top_f + np.log(tot)
    p = e / np.maximum(tot, 1e-300)[:, None]
    gx = -4.0 * np.matmul(R, q[..., None])[..., 0]
    grad = np.matmul(p[:, None, :], gx)[:, 0]
    gn = norm3(grad)
    inv_g = 1.0 / np.maximum(gn, g_min)
    L = np.where(valid.any(axis=1), L, -np.inf)
    dist = np.where(np.isfinite(L), (L - LN_T) * inv_g, -np.inf)
    return Attractor(L=L, grad=grad, p=p, y=y, q=q, gx=gx, dist=dist, inv_g=inv_g)


def attractor_jacobians(
    skel: Skeleton,
    pose: Pose,
    balls: Metaballs,
    s: np.ndarray,
    x: np.ndarray,
    idx: np.ndarray,
    att: Attractor,
    radii: np.ndarray,
    anc: np.ndarray,
    shape: bool = False,
    frame: int = 0,
):
    """Jacobians of ``L`` (not yet divided by ``|∇L|``) at fixed world points.

    Moving metaball m by a rotation ``δθ_k`` about ``ω_k`` through ``p_k`` changes
    ``−2 d_m`` by ``−g_m · (ω_k × (x − p_k)) δθ_k`` (``g_m`` = its world gradient at
    x); ``∂L = Σ_m p_m ∂(−2 d_m)``.

    Parameters
    ----------
    pose : Pose holding frame ``frame``; idx (N, K); att from :func:`attractor`
    anc : (n, n) bool from :meth:`Skeleton.ancestors`
    shape : also return the radius and centre Jacobians

    Returns
    -------
    J_theta (N, n), J_root (N, 3), J_s (N, G), and when ``shape``: J_radii (N, K, 3)
    (w.r.t. ``radii[idx]``) and J_centres (N, K, 3) (w.r.t. ``center0[idx]``).
    """
    ball_anc = anc[skel.bone_dof[balls.bone]]  # (M, n) bool
    J_root = -att.grad
    # scales: centre c_m moves by Σ_{k anc, group g} R_par(k) o_k + [g_m = g] R_b c0_m
    off_world = np.einsum("kij,kj->ki", pose.R_parent[frame], skel.dof_offset)
    onehot = np.zeros((skel.n_dof, skel.n_groups))
    has = skel.dof_group >= 0
    onehot[np.nonzero(has)[0], skel.dof_group[has]] = 1.0
    dc = np.einsum("mk,ki,kg->mig", ball_anc.astype(float), off_world, onehot)  # (M, 3, G)
    Rb, _ = bone_frames(
        skel,
        Pose(
            pose.R[frame : frame + 1], pose.p[frame : frame + 1], pose.R_parent[frame : frame + 1]
        ),
    )
    Rb = Rb[0]
    own = np.einsum("mij,mj->mi", Rb[balls.bone], balls.center0)
    sel = np.nonzero(balls.group >= 0)[0]
    dc[sel, :, balls.group[sel]] += own[sel]
    N, K = idx.shape
    J_theta, J_s = np.empty((N, skel.n_dof)), np.empty((N, skel.n_groups))
    if not (
        field_kernel.enabled()
        and field_kernel.run(
            attractor_kernel.pose_jacobians,
            np.ascontiguousarray(x, dtype=float),
            np.ascontiguousarray(idx, dtype=np.int64),
            att.p,
            att.gx,
            np.ascontiguousarray(ball_anc),
            np.ascontiguousarray(pose.axes[frame]),
            np.ascontiguousarray(pose.p[frame]),
            dc,
            J_theta,
            J_s,
        )
    ):
        pg = att.p[..., None] * att.gx  # (N, K, 3): p_m ∇(−2 d_m)
        G = np.matmul(np.swapaxes(ball_anc[idx].astype(float), 1, 2), pg)  # (N, n, 3)
        w = pose.axes[frame]  # (n, 3)
        d = np.asarray(x, float)[:, None, :] - pose.p[frame][None]  # (N, n, 3)
        wxd = np.stack(
            [
                w[None, :, 1] * d[..., 2] - w[None, :, 2] * d[..., 1],
                w[None, :, 2] * d[..., 0] - w[None, :, 0] * d[..., 2],
                w[None, :, 0] * d[..., 1] - w[None, :, 1] * d[..., 0],
            ],
            axis=-1,
        )
        J_theta = -np.sum(G * wxd, axis=-1)  # Σ_{m below k} p_m ∇(−2 d_m) · ω_k × (x − p_k)
        J_s = -np.matmul(pg.reshape(N, 1, 3 * K), dc[idx].reshape(N, 3 * K, -1))[:, 0]
    if not shape:
        return J_theta, J_root, J_s
    scale = np.where(balls.group >= 0, np.asarray(s, float)[np.maximum(balls.group, 0)], 1.0)
    J_radii, J_centres = np.empty((N, K, 3)), np.empty((N, K, 3))
    if field_kernel.enabled() and field_kernel.run(
        attractor_kernel.shape_jacobians,
        np.ascontiguousarray(idx, dtype=np.int64),
        att.p,
        att.y,
        att.q,
        np.ascontiguousarray(balls.rot, dtype=float),
        np.ascontiguousarray(radii, dtype=float),
        scale,
        J_radii,
        J_centres,
    ):
        return J_theta, J_root, J_s, J_radii, J_centres
    J_radii = 4.0 * att.p[..., None] * att.y**2 / radii[idx] ** 3
    J_centres = (
        4.0 * (att.p * scale[idx])[..., None] * np.matmul(balls.rot[idx], att.q[..., None])[..., 0]
    )
    return J_theta, J_root, J_s, J_radii, J_centres


def scatter(J_k: np.ndarray, idx: np.ndarray, valid: np.ndarray, M: int) -> np.ndarray:
    """Dense (N, 3M) Jacobian from per-member blocks ``J_k`` (N, K, 3); a row's valid
    entries of ``idx`` must be distinct metaballs (as :func:`gather` gives them)."""
    N = len(idx)
    out = np.zeros((N, M, 3))
    rows = np.broadcast_to(np.arange(N)[:, None], idx.shape)
    ok = np.asarray(valid, bool)
    out[rows[ok], idx[ok]] = J_k[ok]  # a point's valid members are distinct metaballs
    return out.reshape(N, 3 * M)
