"""Self-calibrating bundle adjustment with a reference bar (wand).

Unknowns: every camera's exterior orientation (Rodrigues vector, translation) and the
interior parameters chosen free (of ``f, aspect, cx, cy, k1, k2, k3, p1, p2``, see
:data:`core.camera.INTRINSIC_NAMES`), plus both targets' 3-D positions at every wand
location.  Observations: the targets' image coordinates (pixels).  Condition
equations: ``|X_A - X_B| = L`` for every location, weighted as pseudo-observations
with σ_L.  Datum: the first camera's exterior orientation is fixed (the world is its
camera frame unless the initial cameras say otherwise), the scale comes from L.

The adjustment runs twice: first with a robust loss (``soft_l1``, ``f_scale`` in
pixels) to find bad blobs, then, with those observations flagged and removed, with
plain least squares for the final values and their precisions ``Σ = σ0² (JᵀJ)⁻¹``.
The default solver is Levenberg–Marquardt on the sparse analytic Jacobian with the
target coordinates eliminated through the Schur complement (each wand location is a
6×6 block); ``scipy.optimize.least_squares`` (trf, ``x_scale='jac'``, ``soft_l1``,
analytic sparse Jacobian or ``jac_sparsity``) is available as ``solver="scipy:…"`` but
its LSMR steps converge far more slowly on this problem (tens of seconds instead of
well under one for 150 locations).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from .bundle_flags import (
    FLAG_WEIGHT,
    flag_by_intersection,
    flag_observations,
    intersect_targets,
    label_swaps,
    residual_norms,
    robust_scale,
)
from .bundle_solver import normal_blocks
from .bundle_solver import solve as solve_problem
from .camera import (
    INTRINSIC_NAMES,
    N_PARAMS,
    PARAM_NAMES,
    Camera,
    pack_camera,
    project_params,
    unpack_camera,
)

#: Interior parameters free by default.
DEFAULT_FREE = ("f", "cx", "cy", "k1", "k2")


@dataclass
class BundleResult:
    """Outcome of :func:`adjust_wand`.

    Attributes
    ----------
    success : bool
    message : str
    cameras : list of Camera
        Adjusted cameras (world = the datum of the first camera).
    xyz : ndarray, shape (F, 2, 3)
        Adjusted targets A, B per wand location, metres.
    rmse_px : ndarray, shape (C,)
        Reprojection RMSE per camera over inlier observations (per coordinate), px.
    rms_px : float
        Overall reprojection RMSE (per coordinate), px.
    sigma0 : float
        A-posteriori σ of unit weight (pixels, including the length conditions).
    param_sigma : ndarray, shape (C, 15)
        σ of each camera parameter in :data:`core.camera.PARAM_NAMES` order (NaN when
        fixed); translation in m, rotation in rad, f/cx/cy in px.
    xyz_sigma : ndarray, shape (F, 2, 3)
        σ of the target coordinates, metres.
    length_residual_m : ndarray, shape (F,)
        ``|X_A - X_B| - L`` at the solution, metres (NaN for unused locations).
    outliers : ndarray, shape (F, C, 2), bool
        Observations flagged as bad blobs (kept at weight :data:`FLAG_WEIGHT`, so out
        of every figure above).
    used : ndarray, shape (F,), bool
        Locations that entered the adjustment (both targets seen in ≥ 2 cameras and
        intersected in front of them).
    free : tuple of str
        The interior parameters that were free.
    nfev : int
        Function evaluations over all passes.
    outlier_threshold_px : float
        Residual length above which an observation was flagged (last round), px.
    uv : ndarray, shape (F, C, 2, 2)
        The observations as adjusted: the input with A/B exchanged where ``swapped``.
    swapped : ndarray, shape (F, C), bool
        Images whose A/B labels the robust rounds exchanged (a bad blob had misled the
        epipolar labelling); ``outliers`` refers to ``uv``.
    """

    success: bool
    message: str
    cameras: list[Camera]
    xyz: np.ndarray
    rmse_px: np.ndarray
    rms_px: float
    sigma0: float
    param_sigma: np.ndarray
    xyz_sigma: np.ndarray
    length_residual_m: np.ndarray
    outliers: np.ndarray
    used: np.ndarray
    free: tuple = ()
    nfev: int = 0
    names: list = field(default_factory=list)
    outlier_threshold_px: float = float("nan")
    uv: np.ndarray | None = None
    swapped: np.ndarray | None = None

    def sigma_of(self, cam: int, name: str) -> float:
        """σ of one camera parameter by name (see :data:`core.camera.PARAM_NAMES`)."""
        return float(self.param_sigma[cam, PARAM_NAMES.index(name)])


class _Problem:
    """Packing, residuals and sparse Jacobian of one adjustment (all arrays fixed)."""

    def __init__(self, params0, xyz0, uv, obs, length, free, w_len, w_obs=None):
        self.params0 = params0  # (C, 15)
        self.C = params0.shape[0]
        self.F = xyz0.shape[0]
        self.uv = uv
        self.obs = obs  # (M, 3): frame, camera, target
        self.length = length
        self.w_len = w_len
        free_idx = [6 + INTRINSIC_NAMES.index(n) for n in free]
        mask = np.zeros((self.C, N_PARAMS), dtype=bool)
        mask[:, free_idx] = True
        mask[1:, :6] = True  # datum: camera 1 exterior fixed
        self.mask = mask
        # column of each (camera, parameter), -1 when fixed
        col = -np.ones((self.C, N_PARAMS), dtype=int)
        col[mask] = np.arange(mask.sum())
        self.cam_col = col
        self.n_cam = int(mask.sum())
        self.n = self.n_cam + self.F * 6
        f, c, k = obs.T
        self.pt_col = self.n_cam + (f * 2 + k)[:, None] * 3 + np.arange(3)  # (M, 3)
        self.target = uv[f, c, k]  # (M, 2)
        self.M = obs.shape[0]
        self.m = 2 * self.M + self.F
        # weight of each observation's residual pair: 1, or ε for a flagged bad blob
        # (kept in the problem so that its residual is predicted by the others)
        self.w_obs = np.ones(self.M) if w_obs is None else np.asarray(w_obs, dtype=float)

    def pack(self, params, xyz):
        return np.concatenate([params[self.mask], xyz.ravel()])

    def unpack(self, x):
        params = self.params0.copy()
        params[self.mask] = x[: self.n_cam]
        return params, x[self.n_cam :].reshape(self.F, 2, 3)

    def residuals(self, x, jacobian=False):
        params, xyz = self.unpack(x)
        f, c, k = self.obs.T
        out = project_params(params[c], xyz[f, k], jacobian=jacobian)
        uv = out[0] if jacobian else out
        w = self.w_obs[:, None]
        r_obs = (w * (uv - self.target)).ravel()
        d = xyz[:, 0] - xyz[:, 1]
        dist = np.linalg.norm(d, axis=1)
        r_len = self.w_len * (dist - self.length)
        r = np.concatenate([r_obs, r_len])
        if not jacobian:
            return r
        _, J_cam, J_xyz = out
        J_cam, J_xyz = J_cam * w[:, :, None], J_xyz * w[:, :, None]
        rows, cols, vals = [], [], []
        obs_rows = 2 * np.arange(self.M)[:, None] + np.arange(2)  # (M, 2)
        cc = self.cam_col[c]  # (M, 15)
        for p in range(N_PARAMS):
            use = cc[:, p] >= 0
            if not np.any(use):
                continue
            rows.append(obs_rows[use].ravel())
            cols.append(np.repeat(cc[use, p], 2))
            vals.append(J_cam[use, :, p].ravel())
        rows.append(np.repeat(obs_rows, 3, axis=1).ravel())
        cols.append(np.tile(self.pt_col, (1, 2)).ravel())
        vals.append(J_xyz.ravel())
        u = d / np.where(dist > 0, dist, 1.0)[:, None]  # (F, 3)
        len_rows = 2 * self.M + np.arange(self.F)
        base = self.n_cam + np.arange(self.F) * 6
        rows.append(np.repeat(len_rows, 6))
        cols.append((base[:, None] + np.arange(6)).ravel())
        vals.append((self.w_len * np.concatenate([u, -u], axis=1)).ravel())
        J = sp.csr_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
            shape=(self.m, self.n),
        )
        return r, J

    def sparsity(self):
        f, c, k = self.obs.T
        rows, cols = [], []
        obs_rows = 2 * np.arange(self.M)[:, None] + np.arange(2)
        cc = self.cam_col[c]
        for p in range(N_PARAMS):
            use = cc[:, p] >= 0
            rows.append(obs_rows[use].ravel())
            cols.append(np.repeat(cc[use, p], 2))
        rows.append(np.repeat(obs_rows, 3, axis=1).ravel())
        cols.append(np.repeat(self.pt_col[:, None, :], 2, axis=1).ravel())
        base = self.n_cam + np.arange(self.F) * 6
        rows.append(np.repeat(2 * self.M + np.arange(self.F), 6))
        cols.append((base[:, None] + np.arange(6)).ravel())
        r, cl = np.concatenate(rows), np.concatenate(cols)
        return sp.csr_matrix((np.ones(r.size), (r, cl)), shape=(self.m, self.n))


def adjust_wand(
    cameras: list[Camera],
    uv: np.ndarray,
    xyz0: np.ndarray,
    length_m: float,
    free: tuple[str, ...] = DEFAULT_FREE,
    sigma_px: float = 0.1,
    sigma_length_m: float = 1e-4,
    f_scale_px: float = 1.0,
    outlier_px: float | None = None,
    outlier_sigma: float = 5.0,
    outlier_floor_px: float = 0.25,
    robust: bool = True,
    solver: str = "lm",
    max_iter: int = 100,
    max_rounds: int = 6,
) -> BundleResult:
    """Self-calibrating bundle adjustment of wand observations, robust to bad blobs.

    Robust scheme (``robust=True``): start by flagging, with the initial cameras,
    observations a leave-one-out intersection shows off by more than ``max(20 px,
    outlier_px)`` and re-intersecting their targets from the rest.  Then rounds of
    (1) adjustment with the ``soft_l1`` loss (``f_scale_px``), flagged observations
    kept at weight :data:`FLAG_WEIGHT`; (2) residual lengths of *all* observations
    against the robust scale σ̂ (:func:`robust_scale` of the unflagged ones);
    (3) flags decided afresh by :func:`flag_observations` with the threshold
    ``outlier_px`` or ``max(outlier_floor_px, outlier_sigma · σ̂)``, so that
    observations whose residual becomes small again are re-admitted.  The rounds stop
    when the flags settle.  A final plain least-squares pass with the flags gives the
    values and their precisions ``Σ = σ0² (JᵀJ)⁻¹``.

    Parameters
    ----------
    cameras : list of Camera, length C
        Initial cameras; the first one's exterior orientation is the datum (fixed).
    uv : ndarray, shape (F, C, 2, 2)
        Image coordinates (px) of targets A (index 0) and B (index 1) at every wand
        location in every camera; NaN where not measured.
    xyz0 : ndarray, shape (F, 2, 3)
        Initial target positions (world of the initial cameras), metres.
    length_m : float
        Bar length L, metres.
    free : tuple of str
        Interior parameters to adjust, names from :data:`core.camera.INTRINSIC_NAMES`.
    sigma_px, sigma_length_m : float
        A-priori σ of an image coordinate and of the bar length; they weight the
        condition equations against the image observations.
    f_scale_px : float
        Soft threshold of the robust loss, pixels.
    outlier_px : float, optional
        Fixed flagging threshold on the residual length, px (default: from σ̂).
    outlier_sigma, outlier_floor_px : float
        Threshold ``max(outlier_floor_px, outlier_sigma · σ̂)`` when ``outlier_px``
        is not given.
    robust : bool
        Robust loss and flagging (else plain least squares only).
    solver : {"lm", "scipy:analytic", "scipy:2-point"}
        ``"lm"``: Levenberg–Marquardt with the points eliminated by the Schur
        complement (exact, fast).  ``"scipy:analytic"``: ``least_squares`` (trf,
        ``x_scale='jac'``, ``soft_l1``) with the sparse analytic Jacobian;
        ``"scipy:2-point"``: the same with finite differences and ``jac_sparsity``.
    max_iter : int
        Iterations (``lm``) or function evaluations (scipy) per pass.
    max_rounds : int
        Most robust adjust-and-flag rounds.

    Returns
    -------
    BundleResult
    """
    bad = [n for n in free if n not in INTRINSIC_NAMES]
    if bad:
        raise ValueError(f"unknown interior parameters {bad}; choose from {INTRINSIC_NAMES}")
    uv = np.asarray(uv, dtype=float)
    F, C = uv.shape[:2]
    if uv.shape != (F, C, 2, 2) or C != len(cameras):
        raise ValueError(f"uv must have shape (F, {len(cameras)}, 2, 2), got {uv.shape}")
    uv = uv.copy()  # labels may be exchanged
    swapped = np.zeros((F, C), dtype=bool)
    xyz = np.asarray(xyz0, dtype=float).reshape(F, 2, 3).copy()
    seen = np.all(np.isfinite(uv), axis=-1)  # (F, C, 2)
    base = np.all(seen.sum(axis=1) >= 2, axis=1)  # (F,) both targets ≥ 2 views
    seen &= base[:, None, None]
    xyz[~base] = np.nan
    params = np.stack([pack_camera(c) for c in cameras])
    w_len = sigma_px / sigma_length_m
    flags = np.zeros((F, C, 2), dtype=bool)
    if robust:
        thr0 = max(20.0, outlier_px or 0.0)
        flags = flag_by_intersection(cameras, uv, seen, thr0)
        again = intersect_targets(cameras, uv, seen & ~flags)
        redo = np.any(flags, axis=1)[..., None] & np.isfinite(again)
        xyz = np.where(redo, again, xyz)

    def solve(flags, loss):
        rn = residual_norms(params, xyz, uv, seen)
        # both targets seen by ≥ 2 unflagged views (else the location waits outside the
        # adjustment, its targets re-intersected every round) and in front of the cameras
        incl = (
            base
            & np.all((seen & ~flags).sum(axis=1) >= 2, axis=1)
            & np.all(np.isfinite(xyz), axis=(1, 2))
            & ~np.any(seen & ~np.isfinite(rn), axis=(1, 2))
        )
        fidx = np.flatnonzero(incl)
        obs = np.argwhere(seen[fidx])
        w_obs = np.where(flags[fidx][tuple(obs.T)], FLAG_WEIGHT, 1.0)
        prob = _Problem(params, xyz[fidx], uv[fidx], obs, length_m, free, w_len, w_obs)
        sol = solve_problem(prob, prob.pack(params, xyz[fidx]), loss, f_scale_px, solver, max_iter)
        return prob, sol, fidx

    def update(prob, sol, fidx, thr):
        """New cameras and targets; targets of the locations left out are intersected
        afresh with the new cameras, leaving out the view that a leave-one-out
        intersection finds off by more than ``thr`` (so that they can come back)."""
        p, xyz_f = prob.unpack(sol.x)
        cams = [unpack_camera(p[c], "", cameras[c].size) for c in range(C)]
        out = np.ones(F, dtype=bool)
        out[fidx] = False
        out &= base
        new = np.full((F, 2, 3), np.nan)
        if np.any(out):
            loo = flag_by_intersection(cams, uv[out], seen[out], thr)
            again = intersect_targets(cams, uv[out], seen[out] & ~loo)
            new[out] = np.where(
                np.isfinite(again), again, intersect_targets(cams, uv[out], seen[out])
            )
        new[fidx] = xyz_f
        new[~base] = np.nan
        return p, new

    nfev, thr = 0, outlier_px
    loss = "soft_l1" if robust else "linear"
    for _ in range(max_rounds if robust else 0):
        prob, sol, fidx = solve(flags, loss)
        nfev += sol.nfev
        params, xyz = update(prob, sol, fidx, thr or 20.0)
        rn = residual_norms(params, xyz, uv, seen)
        swap = label_swaps(params, xyz, uv, seen, rn, thr if thr else 20.0)
        if np.any(swap):
            uv[swap] = uv[swap][:, ::-1]
            swapped ^= swap
            rn = residual_norms(params, xyz, uv, seen)
        scale = robust_scale(rn[~flags])
        if outlier_px is None:
            thr = max(outlier_floor_px, outlier_sigma * scale)
        new = flag_observations(rn, seen, thr, flags)
        if np.array_equal(new, flags):
            break
        flags = new
    prob, sol, fidx = solve(flags, "linear")
    nfev += sol.nfev
    params, xyz_all = update(prob, sol, fidx, thr or 20.0)
    used = np.zeros(F, dtype=bool)
    used[fidx] = True
    xyz_f = xyz_all[fidx]
    r, J = prob.residuals(sol.x, jacobian=True)
    inl = prob.w_obs == 1.0  # (M,)
    r_obs = r[: 2 * prob.M].reshape(-1, 2)
    # redundancy: inlier coordinates + conditions − camera unknowns − the target
    # coordinates the inliers determine (min(3, 2 · views) per target)
    f, _, k = prob.obs.T
    views = np.zeros((prob.F, 2))
    np.add.at(views, (f[inl], k[inl]), 1)
    dof = max(2 * int(inl.sum()) + prob.F - prob.n_cam - int(np.minimum(3, 2 * views).sum()), 1)
    sigma0 = float(np.sqrt((np.sum(r_obs[inl] ** 2) + np.sum(r[2 * prob.M :] ** 2)) / dof))
    param_sigma = np.full((C, N_PARAMS), np.nan)
    xyz_sigma = np.full((F, 2, 3), np.nan)
    Ncc, Npc, Bp = normal_blocks((J.T @ J).tocsr(), prob.n_cam, prob.F)
    try:
        Binv = np.linalg.inv(Bp)
        E = np.einsum("fij,fjn->fin", Binv, Npc)
        S = Ncc - np.einsum("fin,fim->nm", Npc, E)
        Qcc = np.linalg.inv(S)
        q_p = np.einsum("fii->fi", Binv) + np.einsum("fin,nm,fim->fi", E, Qcc, E)
        param_sigma[prob.mask] = sigma0 * np.sqrt(np.abs(np.diag(Qcc)))
        xyz_sigma[fidx] = (sigma0 * np.sqrt(np.abs(q_p))).reshape(-1, 2, 3)
    except np.linalg.LinAlgError:
        pass  # singular normal matrix: σ stay NaN
    xyz = np.full((F, 2, 3), np.nan)
    xyz[fidx] = xyz_f
    rmse = np.full(C, np.nan)
    for c in range(C):  # C cameras, not points
        sel = (prob.obs[:, 1] == c) & inl
        if np.any(sel):
            rmse[c] = float(np.sqrt(np.mean(r_obs[sel] ** 2)))
    lres = np.full(F, np.nan)
    lres[fidx] = np.linalg.norm(xyz_f[:, 0] - xyz_f[:, 1], axis=1) - length_m
    cams = [unpack_camera(params[c], cameras[c].name, cameras[c].size) for c in range(C)]
    return BundleResult(
        success=bool(sol.success),
        message=str(sol.message),
        cameras=cams,
        xyz=xyz,
        rmse_px=rmse,
        rms_px=float(np.sqrt(np.mean(r_obs[inl] ** 2))),
        sigma0=sigma0,
        param_sigma=param_sigma,
        xyz_sigma=xyz_sigma,
        length_residual_m=lres,
        outliers=flags,
        used=used,
        free=tuple(free),
        nfev=int(nfev),
        names=[c.name for c in cameras],
        outlier_threshold_px=float(thr or np.nan),
        uv=uv,
        swapped=swapped,
    )
