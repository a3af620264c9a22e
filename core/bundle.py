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
from scipy.optimize import least_squares

from .camera import (
    INTRINSIC_NAMES,
    N_PARAMS,
    PARAM_NAMES,
    Camera,
    pack_camera,
    project_params,
    unpack_camera,
)
from .intersect import triangulate

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
        Observations flagged as bad blobs by the robust pass.
    used : ndarray, shape (F,), bool
        Locations that entered the adjustment (both targets seen in ≥ 2 cameras).
    free : tuple of str
        The interior parameters that were free.
    nfev : int
        Function evaluations over both passes.
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

    def sigma_of(self, cam: int, name: str) -> float:
        """σ of one camera parameter by name (see :data:`core.camera.PARAM_NAMES`)."""
        return float(self.param_sigma[cam, PARAM_NAMES.index(name)])


class _Problem:
    """Packing, residuals and sparse Jacobian of one adjustment (all arrays fixed)."""

    def __init__(self, params0, xyz0, uv, obs, length, free, w_len):
        self.params0 = params0                      # (C, 15)
        self.C = params0.shape[0]
        self.F = xyz0.shape[0]
        self.uv = uv
        self.obs = obs                               # (M, 3): frame, camera, target
        self.length = length
        self.w_len = w_len
        free_idx = [6 + INTRINSIC_NAMES.index(n) for n in free]
        mask = np.zeros((self.C, N_PARAMS), dtype=bool)
        mask[:, free_idx] = True
        mask[1:, :6] = True                          # datum: camera 1 exterior fixed
        self.mask = mask
        # column of each (camera, parameter), -1 when fixed
        col = -np.ones((self.C, N_PARAMS), dtype=int)
        col[mask] = np.arange(mask.sum())
        self.cam_col = col
        self.n_cam = int(mask.sum())
        self.n = self.n_cam + self.F * 6
        f, c, k = obs.T
        self.pt_col = self.n_cam + (f * 2 + k)[:, None] * 3 + np.arange(3)   # (M, 3)
        self.target = uv[f, c, k]                                             # (M, 2)
        self.M = obs.shape[0]
        self.m = 2 * self.M + self.F

    def pack(self, params, xyz):
        return np.concatenate([params[self.mask], xyz.ravel()])

    def unpack(self, x):
        params = self.params0.copy()
        params[self.mask] = x[: self.n_cam]
        return params, x[self.n_cam:].reshape(self.F, 2, 3)

    def residuals(self, x, jacobian=False):
        params, xyz = self.unpack(x)
        f, c, k = self.obs.T
        out = project_params(params[c], xyz[f, k], jacobian=jacobian)
        uv = out[0] if jacobian else out
        r_obs = (uv - self.target).ravel()
        d = xyz[:, 0] - xyz[:, 1]
        dist = np.linalg.norm(d, axis=1)
        r_len = self.w_len * (dist - self.length)
        r = np.concatenate([r_obs, r_len])
        if not jacobian:
            return r
        _, J_cam, J_xyz = out
        rows, cols, vals = [], [], []
        obs_rows = 2 * np.arange(self.M)[:, None] + np.arange(2)              # (M, 2)
        cc = self.cam_col[c]                                                   # (M, 15)
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
        u = d / np.where(dist > 0, dist, 1.0)[:, None]                        # (F, 3)
        len_rows = 2 * self.M + np.arange(self.F)
        base = self.n_cam + np.arange(self.F) * 6
        rows.append(np.repeat(len_rows, 6))
        cols.append((base[:, None] + np.arange(6)).ravel())
        vals.append((self.w_len * np.concatenate([u, -u], axis=1)).ravel())
        J = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(self.m, self.n))
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


def _soft_l1(r2, f_scale):
    """Robust cost ``f² · 2 (sqrt(1 + r²/f²) - 1)`` and IRLS weights per residual pair."""
    z = r2 / f_scale**2
    return f_scale**2 * 2.0 * (np.sqrt(1.0 + z) - 1.0), 1.0 / np.sqrt(1.0 + z)


class _Solution:
    def __init__(self, x, success, message, nfev):
        self.x, self.success, self.message, self.nfev = x, success, message, nfev


def _lm(problem, x, loss, f_scale, max_iter, tol=1e-10):
    """Levenberg–Marquardt on the sparse normal equations, points eliminated (Schur).

    Every wand location owns a 6×6 diagonal block (both targets, coupled by the
    length condition), so the reduced system has only the camera unknowns.  A robust
    ``soft_l1`` loss is applied by iteratively reweighting the observation pairs.
    """
    nc, M = problem.n_cam, problem.M

    def cost_weights(r):
        r2 = np.sum(r[: 2 * M].reshape(M, 2) ** 2, axis=1)
        if loss == "linear":
            rho, w = r2, np.ones(M)
        else:
            rho, w = _soft_l1(r2, f_scale)
        return 0.5 * (rho.sum() + np.sum(r[2 * M:] ** 2)), np.concatenate(
            [np.repeat(w, 2), np.ones(problem.F)])

    r, J = problem.residuals(x, jacobian=True)
    cost, w = cost_weights(r)
    lam, nfev = 1e-3, 1
    for it in range(max_iter):
        Jw = sp.diags(w) @ J
        N = (J.T @ Jw).tocsr()
        g = -(Jw.T @ r)
        step = _schur_solve(N, g, nc, problem.F, lam)
        while True:
            x_new = x + step
            r_new = problem.residuals(x_new)
            nfev += 1
            cost_new, _ = cost_weights(r_new)
            if np.isfinite(cost_new) and cost_new <= cost:
                break
            lam *= 10.0
            if lam > 1e12:
                return _Solution(x, True, "converged (no further decrease)", nfev)
            step = _schur_solve(N, g, nc, problem.F, lam)
        lam = max(lam / 10.0, 1e-12)
        rel = (cost - cost_new) / max(cost, 1e-300)
        x = x_new
        r, J = problem.residuals(x, jacobian=True)
        cost, w = cost_weights(r)
        if rel < tol or np.max(np.abs(step)) < 1e-12:
            return _Solution(x, True, f"converged after {it + 1} iterations", nfev)
    return _Solution(x, False, f"no convergence in {max_iter} iterations", nfev)


def _blocks(N, nc, F):
    """Camera block (nc, nc) dense, coupling (F, 6, nc), point blocks (F, 6, 6)."""
    Ncc = N[:nc, :nc].toarray()
    Npc = N[nc:, :nc].toarray().reshape(F, 6, nc)
    Npp = N[nc:, nc:].tocoo()
    B = np.zeros((F, 6, 6))
    B[Npp.row // 6, Npp.row % 6, Npp.col % 6] = Npp.data
    return Ncc, Npc, B


def _schur_solve(N, g, nc, F, lam):
    Ncc, Npc, B = _blocks(N, nc, F)
    Ncc = Ncc + lam * np.diag(np.diag(Ncc))
    idx = np.arange(6)
    B = B.copy()
    B[:, idx, idx] *= 1.0 + lam
    Binv = np.linalg.inv(B)
    gc, gp = g[:nc], g[nc:].reshape(F, 6)
    E = np.einsum("fij,fjn->fin", Binv, Npc)                    # B⁻¹ N_pc
    S = Ncc - np.einsum("fin,fim->nm", Npc, E)
    rhs = gc - np.einsum("fin,fi->n", E, gp)
    dc = np.linalg.solve(S, rhs) if nc else np.zeros(0)
    dp = np.einsum("fij,fj->fi", Binv, gp) - E @ dc
    return np.concatenate([dc, dp.ravel()])


def _scipy(problem, x0, loss, f_scale, jac_mode, max_nfev):
    """``scipy.optimize.least_squares`` path (slower to converge on large problems)."""
    kw = dict(x_scale="jac", loss=loss, f_scale=f_scale, method="trf", tr_solver="lsmr",
              max_nfev=max_nfev, ftol=1e-12, xtol=1e-12, gtol=1e-10)
    if jac_mode == "analytic":
        sol = least_squares(problem.residuals, x0,
                            jac=lambda x: problem.residuals(x, jacobian=True)[1], **kw)
    else:
        sol = least_squares(problem.residuals, x0, jac_sparsity=problem.sparsity(), **kw)
    return _Solution(sol.x, bool(sol.success), str(sol.message), int(sol.nfev))


def _solve(problem, x0, loss, f_scale, solver, max_iter):
    if solver == "lm":
        return _lm(problem, x0, loss, f_scale, max_iter)
    return _scipy(problem, x0, loss, f_scale, solver.split(":")[1], max_iter)


def _flag_by_intersection(cameras, uv, seen, thr):
    """Bad blobs by leave-one-out forward intersection of every target.

    A target seen in ≥ 3 cameras whose full intersection leaves a residual above
    ``thr`` (px) gets the one camera flagged whose removal makes the rest fit; if no
    single removal does, every view off the best fit is flagged.  A target seen in two
    cameras that do not fit each other cannot tell which is wrong: both are flagged.

    Parameters: ``uv`` (F, C, 2, 2), ``seen`` (F, C, 2) bool.  Returns (F, C, 2) bool.
    """
    F, C = uv.shape[:2]
    pts = np.where(seen[..., None], uv, np.nan).transpose(0, 2, 1, 3).reshape(F * 2, C, 2)
    n = np.isfinite(pts[..., 0]).sum(axis=1)

    def residuals(mask_cam):
        p = pts.copy()
        if mask_cam is not None:
            p[:, mask_cam] = np.nan
        xyz = triangulate(cameras, p, iterations=5).xyz
        pred = np.stack([c.project(xyz) for c in cameras], axis=1)
        return np.linalg.norm(pred - pts, axis=2)                   # (G, C), NaN unseen

    with np.errstate(invalid="ignore"):
        full = residuals(None)
        bad_full = np.nanmax(np.where(np.isfinite(full), full, -1.0), axis=1) > thr
        flags = np.zeros((F * 2, C), dtype=bool)
        best_rest = np.full(F * 2, np.inf)
        best_cam = np.full(F * 2, -1)
        loo = []
        for j in range(C):  # one pass per camera, all targets at once
            res_j = residuals(j)
            rest = np.where(np.arange(C) == j, -1.0, np.where(np.isfinite(res_j), res_j, -1.0))
            worst = rest.max(axis=1)
            better = (n >= 3) & np.isfinite(pts[:, j, 0]) & (worst < best_rest)
            best_rest[better], best_cam[better] = worst[better], j
            loo.append(res_j)
        loo = np.stack(loo, axis=1)                                   # (G, Cmask, C)
        single = bad_full & (best_rest <= thr) & (best_cam >= 0)
        g = np.flatnonzero(single)
        flags[g, best_cam[g]] = True
        rest = bad_full & ~single
        g = np.flatnonzero(rest & (best_cam >= 0))
        off = loo[g, best_cam[g]] > thr
        flags[g] = off | (np.arange(C) == best_cam[g][:, None])
        g = np.flatnonzero(rest & (best_cam < 0))
        flags[g] = np.isfinite(pts[g, :, 0])
    return flags.reshape(F, 2, C).transpose(0, 2, 1) & seen


def adjust_wand(cameras: list[Camera], uv: np.ndarray, xyz0: np.ndarray, length_m: float,
                free: tuple[str, ...] = DEFAULT_FREE, sigma_px: float = 0.1,
                sigma_length_m: float = 1e-4, f_scale_px: float = 1.0,
                outlier_px: float | None = None, robust: bool = True,
                solver: str = "lm", max_iter: int = 100) -> BundleResult:
    """Self-calibrating bundle adjustment of wand observations.

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
        Flag an observation whose residual (norm) exceeds this; default
        ``max(1 px, 6 · robust σ)`` of the robust pass.
    robust : bool
        Run the robust pass and flag outliers (else plain least squares only).
    solver : {"lm", "scipy:analytic", "scipy:2-point"}
        ``"lm"``: Levenberg–Marquardt with the points eliminated by the Schur
        complement (exact, fast).  ``"scipy:analytic"``: ``least_squares`` (trf,
        ``x_scale='jac'``, ``soft_l1``) with the sparse analytic Jacobian;
        ``"scipy:2-point"``: the same with finite differences and ``jac_sparsity``.
    max_iter : int
        Iterations (``lm``) or function evaluations (scipy) per pass.

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
    xyz0 = np.asarray(xyz0, dtype=float).reshape(F, 2, 3)
    seen = np.all(np.isfinite(uv), axis=-1)                      # (F, C, 2)
    used = np.all(seen.sum(axis=1) >= 2, axis=1) & np.all(np.isfinite(xyz0), axis=(1, 2))
    fidx = np.flatnonzero(used)
    params0 = np.stack([pack_camera(c) for c in cameras])
    w_len = sigma_px / sigma_length_m

    def build(valid):
        obs = np.argwhere(valid[fidx])
        obs[:, 0] = np.arange(fidx.size)[obs[:, 0]] if obs.size else obs[:, 0]
        return _Problem(params0, xyz0[fidx], uv[fidx], obs, length_m, free, w_len)

    outliers = np.zeros((F, C, 2), dtype=bool)
    base_used = used.copy()
    loss = "soft_l1" if robust else "linear"
    nfev = 0
    thr = outlier_px
    # Adjust, flag bad blobs (leave-one-out intersection with the adjusted cameras, and
    # misfits of the adjustment), adjust again without them, until the flags settle.
    # With f_scale ≫ the noise the soft_l1 loss weighs inliers like least squares.
    for _ in range(4 if robust else 1):
        valid = seen & ~outliers
        used = base_used & np.all(valid.sum(axis=1) >= 2, axis=1)
        fidx = np.flatnonzero(used)
        prob = build(valid)
        sol = _solve(prob, prob.pack(params0, xyz0[fidx]), loss, f_scale_px, solver, max_iter)
        nfev += sol.nfev
        params, xyz_f = prob.unpack(sol.x)
        params0, xyz0 = params, xyz0.copy()
        xyz0[fidx] = xyz_f
        if not robust:
            break
        r = prob.residuals(sol.x)[: 2 * prob.M].reshape(-1, 2)
        if outlier_px is None:
            thr = max(1.0, 6.0 * 1.4826 * float(np.median(np.abs(r))))
        cams_now = [unpack_camera(params[c], "", cameras[c].size) for c in range(C)]
        new = _flag_by_intersection(cams_now, uv, seen & base_used[:, None, None], thr)
        all_obs = np.argwhere(seen[fidx])                       # incl. flagged ones
        pred = project_params(params[all_obs[:, 1]], xyz_f[all_obs[:, 0], all_obs[:, 2]],
                              jacobian=False)
        rn = np.linalg.norm(pred - uv[fidx][tuple(all_obs.T)], axis=1)
        far = all_obs[~(rn <= thr)]
        new[fidx[far[:, 0]], far[:, 1], far[:, 2]] = True
        new |= outliers & ~used[:, None, None]     # dropped locations keep their flags
        if np.array_equal(new, outliers):
            break
        outliers = new
    r, J = prob.residuals(sol.x, jacobian=True)
    r_obs = r[: 2 * prob.M].reshape(-1, 2)
    dof = max(prob.m - prob.n, 1)
    sigma0 = float(np.sqrt(np.sum(r**2) / dof))
    param_sigma = np.full((C, N_PARAMS), np.nan)
    xyz_sigma = np.full((F, 2, 3), np.nan)
    Ncc, Npc, Bp = _blocks((J.T @ J).tocsr(), prob.n_cam, prob.F)
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
        sel = prob.obs[:, 1] == c
        if np.any(sel):
            rmse[c] = float(np.sqrt(np.mean(r_obs[sel] ** 2)))
    lres = np.full(F, np.nan)
    lres[fidx] = np.linalg.norm(xyz_f[:, 0] - xyz_f[:, 1], axis=1) - length_m
    cams = [unpack_camera(params[c], cameras[c].name, cameras[c].size) for c in range(C)]
    return BundleResult(
        success=bool(sol.success), message=str(sol.message), cameras=cams, xyz=xyz,
        rmse_px=rmse, rms_px=float(np.sqrt(np.mean(r_obs**2))), sigma0=sigma0,
        param_sigma=param_sigma, xyz_sigma=xyz_sigma, length_residual_m=lres,
        outliers=outliers, used=used, free=tuple(free), nfev=int(nfev),
        names=[c.name for c in cameras])
