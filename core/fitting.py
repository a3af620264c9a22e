"""Weighted least-squares fit of the metaball body to 3-D observations (paper 1, §4).

Observation equations by type, each weighted by its a-priori σ (eq. 12,
``p_i / p_j = σ_j² / σ_i²``; here every residual is divided by its σ):

* **attractor points** (eq. 15, ``Σ_{m ∈ part} exp(−2 d_m(x)) = 0.5`` for a 3-D point x
  assigned to a body part, see :mod:`core.segment`), written as the signed distance
  ``(ln Σ f − ln 0.5) / |∇ ln Σ f|`` in metres (:mod:`core.attractor`) over σ in
  metres, so that every point weighs like a distance whatever its depth or the size
  of its metaballs;
* **joint positions** (clicked or predicted): ``(x_joint(θ, s) − obs) / σ_joint``;
* **occluding contours** (optional, :mod:`core.fit_contours`): the image offset, along
  the contour normal, of each observed silhouette contour point from the model's paired
  rim point, ``n · (z − proj(x(θ, root, shape)))`` over σ in pixels, Huber-weighted;
  the pairs are made afresh at the start of every re-weighting round;
* **silhouette containment** (optional, with the contours,
  :meth:`core.fit_contours.ContourFrame.containment_block`): points inside the
  metaballs of the parts it holds project into every camera's foreground — their
  distance outside it over σ in pixels, Huber-robust, re-evaluated at every state;
* **tracked trajectories** (optional, :mod:`core.fit_trajectory`): a point tracked
  since the previous frame held in its bone's frame, ``x(θ, root, s) − z`` over σ in
  metres, Cauchy-weighted (observes a part's twist and slide, which the surface does not);
* **texture flow** (optional, :mod:`core.fit_flow`): an image corner followed from the
  previous frame in one camera, its lifted surface point held in its bone's frame,
  ``π(x(θ, root, s)) − z`` over σ in pixels, Cauchy-weighted;
* **pose prior** (e.g. the prediction from the previous frames):
  ``(θ − θ_pred) / σ_pred``;
* **soft joint limits** (:func:`core.skeleton.limit_residuals`);
* **shape prior** (weak, keeps unobserved radii and centres near their start):
  ``(radii − radii0) / σ_radius``, ``(centres − centres0) / σ_center``;
* **shape bounds** (hard, relative to a reference shape, by default the metaballs
  passed in — the template): every semi-axis within ``FitSettings.radius_ratio`` of
  the reference's and every centre within ``FitSettings.center_shift`` of the
  reference ball's largest semi-axis of its reference place, per coordinate.  The
  prior alone did not hold a ball whose part had taken another part's points: on the
  default scene a hand ball grew from 3.4 to 35 cm and moved 18 cm to swallow the
  thigh points next to it, then "explained" the reappearing forearm's points, so the
  limb search never moved the arm (right wrist 190 mm off for 25 frames).  (3.0, 1.0)
  against (2.0, 0.75), with free space: demo 15.17 / 14.64 mm, jumps_line3 20.48 /
  60.7 mm (the tighter bounds let the hidden right leg take the hand's points there).

Unknowns per frame: ``θ`` (n) and ``root_xyz`` (3) — the pose; ``s`` (G) and the
metaball radii (3M) and, optionally, the metaball centres in their bones' frames (3M;
the paper fixes them on the bone axis, but real flesh is not centred on the bone) —
the shape; the bone scales can be held (``FitSettings.fit_scales``).  As in the
paper, pose and shape are solved alternately (better convergence from a rough
start), then optionally polished together.  Each solve is Levenberg–Marquardt on
dense normal equations with analytic Jacobians, inside a few re-weighting rounds
(IRLS): the distance scale ``1/|∇ ln Σ f|`` and the Huber weights of the attractor
residuals are frozen within a round, so the Jacobian of a round is exact.  The field
of an attractor point sums the metaballs of its part (eq. 15), optionally also those
of the adjacent parts or of the whole body (:func:`core.attractor.member_table`).
Per frame the result reports the attractor RMSE (log-field units and metres), σ of
every joint angle from the normal matrix, and converged / diverged flags.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .attractor import LN_T, attractor, attractor_jacobians, gather, member_table, scatter
from .lm_solver import levenberg_marquardt
from .metaballs import Metaballs, world_frames
from .skeleton import Skeleton, forward, joint_jacobians, limit_residuals


@dataclass
class Observations:
    """One frame's observations.

    Attributes
    ----------
    xyz : (N, 3) attractor points, world metres
    part : (N,) int — body part (bone index) of each point
    sigma : a-priori σ of an attractor point's distance to the surface, metres
      (scalar or (N,)); include the model's own misfit
    joint_idx : (K,) int — observed joints (index into ``skeleton.joint_names``)
    joint_xyz : (K, 3) metres
    sigma_joint : σ of a joint observation, metres
    theta_pred, sigma_pred : optional pose prior (n,) radians and its σ (scalar or (n,))
    contours : optional :class:`core.fit_contours.ContourFrame` — the frame's silhouette
      contours as a further observation type (σ in pixels, its own settings)
    trajectory : optional :class:`core.fit_trajectory.TrajectoryObs` — tracked points
      held fixed in their bones' frames since the previous frame (rigid motion, metres)
    flow : optional :class:`core.fit_flow.FlowObs` — image corners followed from the
      previous frame in one camera, held fixed in their bones' frames (pixels)
    depth : optional :class:`core.fit_depth.DepthHolds` — joints held along one camera's
      rays where only that view's contours see their part (metres)
    linear_prior : optional ``(A, b)``, A (P, n) and b (P,), already weighted: the prior
      residuals ``A θ − b`` (e.g. :func:`core.fit_chain.chain_prior`, neighbouring
      spine links bending and twisting alike)
    """

    xyz: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    part: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    sigma: float | np.ndarray = 0.004
    joint_idx: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    joint_xyz: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    sigma_joint: float = 0.01
    theta_pred: np.ndarray | None = None
    sigma_pred: float | np.ndarray = 0.2
    contours: object | None = None
    trajectory: object | None = None
    flow: object | None = None
    depth: object | None = None
    linear_prior: tuple | None = None


@dataclass
class FitResult:
    """Result of a fit of one frame (or of the shape over several frames)."""

    theta: np.ndarray
    root_xyz: np.ndarray
    s: np.ndarray
    radii: np.ndarray
    centers: np.ndarray
    rmse_field: float
    rmse_m: float
    theta_sigma: np.ndarray
    converged: bool
    diverged: bool
    message: str = ""
    nfev: int = 0


@dataclass
class FitSettings:
    """Weights and solver settings."""

    sigma_limits: float = 0.05
    sigma_radius: float = 0.05
    robust_scale: float = 3.0  # knee of the robust loss, in σ units of the attractor residual
    robust: str = "huber"  # or "cauchy" (redescending influence)
    rounds: int = 3
    polish: bool = True
    max_nfev: int = 100
    tol: float = 1e-4  # relative cost decrease at which the solve stops
    use_limits: bool = True
    shape_prior: bool = True
    free_centers: bool = False
    fit_scales: bool = True  # bone scales free in the shape solve (else held)
    sigma_center: float = 0.03
    members: str = "part"  # field of a point: "part", "neighbours" or "body" (all)
    irls_rounds: int = 3  # re-weighting rounds (distance scale and Huber weights)
    irls_tol: float = 1e-7  # stop re-weighting when no unknown moved more than this
    g_min: float = 2.0  # floor of |∇ ln F| (1/m) in the distance of deep points
    #: (lowest, highest) ratio of a fitted semi-axis to the reference shape's
    radius_ratio: tuple = (0.33, 3.0)
    #: largest shift of a fitted centre (per coordinate, in its bone's frame), in units
    #: of the reference ball's largest semi-axis
    center_shift: float = 1.0


class _Problem:
    """Residuals and Jacobian for any subset of the unknown blocks, one or more frames."""

    def __init__(
        self,
        skel: Skeleton,
        balls: Metaballs,
        obs: list[Observations],
        settings: FitSettings,
        radii0: np.ndarray,
        centers0: np.ndarray,
        shape_ref: Metaballs | None = None,
    ):
        self.skel, self.balls, self.obs, self.cfg = skel, balls, obs, settings
        self.anc = skel.ancestors()
        self.radii0 = radii0
        self.centers0 = centers0
        self.shape_ref = balls if shape_ref is None else shape_ref
        table, valid = member_table(skel, balls, settings.members)
        self.gathers = []
        for o in obs:
            idx, ok = gather(table, valid, o.part)
            use = ok.any(axis=1)
            sig = np.broadcast_to(np.asarray(o.sigma, float), (len(o.xyz),))[use]
            self.gathers.append(
                (np.asarray(o.xyz, float).reshape(-1, 3)[use], idx[use], ok[use], sig)
            )
        self.frozen: list | None = None

    def freeze(self, theta, root, s, radii, centers) -> None:
        """Fix the point weights (1/(σ |∇L|) times the Huber weight) at this state, so
        that the Jacobian within one Gauss–Newton solve is exact (IRLS)."""
        self.frozen = None
        out = []
        for f in range(len(self.obs)):
            if self.obs[f].contours is not None:  # contour pairs and weights, this state
                b0 = self.balls
                self.obs[f].contours.freeze(
                    self.skel, b0.with_parts(centers, radii), theta[f], root[f], s
                )
            if self.obs[f].trajectory is not None:  # rigid-motion weights, this state
                self.obs[f].trajectory.freeze(self.skel, theta[f], root[f], s)
            if self.obs[f].flow is not None:  # image-motion weights, this state
                self.obs[f].flow.freeze(self.skel, theta[f], root[f], s)
            x, _, _, sig = self.gathers[f]
            if not len(x):
                out.append(np.zeros(0))
                continue
            att = self.attractors(f, theta, root, s, radii, centers)[2]
            w = att.inv_g / sig
            if self.cfg.robust_scale:
                r = (att.L - LN_T) * w
                w = w * (
                    _huber_weights(r, self.cfg.robust_scale)
                    if self.cfg.robust == "huber"
                    else _cauchy_weights(r, self.cfg.robust_scale)
                )
            out.append(w)
        self.frozen = out

    def attractors(self, f, theta, root, s, radii, centers):
        """Pose of frame f, its metaballs and the attractor terms of its points."""
        b0 = self.balls
        balls = b0.with_parts(centers, radii)
        pose = forward(self.skel, theta[f][None], root[f][None], s)
        Rw, cw = world_frames(self.skel, pose, balls, s)
        x, idx, ok, _ = self.gathers[f]
        att = attractor(x, idx, ok, Rw[0], cw[0], radii, self.cfg.g_min)
        return pose, balls, att

    def blocks(self, theta, root, s, radii, centers, shape: bool = True):
        """Residual r (m,) and Jacobian blocks per unknown group for every frame:
        ``(kind, r, J_theta, J_root, J_s, J_radii, J_centers)`` (the last two None
        when not ``shape``)."""
        skel, cfg = self.skel, self.cfg
        M3 = radii.size
        rows = []

        def zeros(k):
            return (
                np.zeros((k, skel.n_dof)),
                np.zeros((k, 3)),
                np.zeros((k, skel.n_groups)),
                np.zeros((k, M3)) if shape else None,
                np.zeros((k, M3)) if shape else None,
            )

        for f, o in enumerate(self.obs):
            parts = []
            x, idx, ok, sig = self.gathers[f]
            if len(x):
                pose, balls, att = self.attractors(f, theta, root, s, radii, centers)
                jac = attractor_jacobians(
                    skel, pose, balls, s, x, idx, att, radii, self.anc, shape=shape
                )
                w = att.inv_g / sig if self.frozen is None else self.frozen[f]
                Jr_ = [jac[0] * w[:, None], jac[1] * w[:, None], jac[2] * w[:, None]]
                if shape:
                    M = len(radii)
                    Jr_.append(scatter(jac[3], idx, ok, M) * w[:, None])
                    Jr_.append(scatter(jac[4], idx, ok, M) * w[:, None])
                else:
                    Jr_ += [None, None]
                parts.append(("point", (att.L - LN_T) * w, *Jr_))
            if o.contours is not None:
                b0 = self.balls
                cb = o.contours.block(
                    skel, b0.with_parts(centers, radii), theta[f], root[f], s, self.anc, shape=shape
                )
                if len(cb[0]):
                    parts.append(("contour", *cb))
                hb = o.contours.containment_block(
                    skel, b0.with_parts(centers, radii), theta[f], root[f], s
                )
                if hb is not None and len(hb[0]):
                    z = zeros(len(hb[0]))
                    parts.append(("containment", *hb, *z[2:]))
            if o.trajectory is not None and len(o.trajectory):
                parts.append(
                    (
                        "trajectory",
                        *o.trajectory.block(
                            skel, theta[f], root[f], s, self.anc, M3 if shape else None
                        ),
                    )
                )
            if o.flow is not None and len(o.flow):
                parts.append(
                    (
                        "flow",
                        *o.flow.block(skel, theta[f], root[f], s, self.anc, M3 if shape else None),
                    )
                )
            if o.depth is not None and len(o.depth):
                db = o.depth.block(skel, theta[f], root[f], s)
                z = zeros(len(db[0]))
                parts.append(("depth", *db, z[3], z[4]))
            if len(o.joint_idx):
                xj, Jt, Js = joint_jacobians(skel, theta[f][None], root[f][None], s)
                w = 1.0 / o.sigma_joint
                k = len(o.joint_idx)
                z = zeros(3 * k)
                parts.append(
                    (
                        "joint",
                        ((xj[0, o.joint_idx] - o.joint_xyz) * w).ravel(),
                        Jt[0, o.joint_idx].reshape(3 * k, -1) * w,
                        np.tile(np.eye(3), (k, 1)) * w,
                        Js[0, o.joint_idx].reshape(3 * k, -1) * w,
                        z[3],
                        z[4],
                    )
                )
            if o.theta_pred is not None:
                w = 1.0 / np.broadcast_to(np.asarray(o.sigma_pred, float), (skel.n_dof,))
                z = zeros(skel.n_dof)
                parts.append(("prior", (theta[f] - o.theta_pred) * w, np.diag(w), *z[1:]))
            if o.linear_prior is not None:
                A, b = o.linear_prior
                z = zeros(len(b))
                parts.append(("chain", A @ theta[f] - b, A, *z[1:]))
            if cfg.use_limits:
                r, d = limit_residuals(skel, theta[f][None], cfg.sigma_limits)
                z = zeros(skel.n_dof)
                parts.append(("limit", r[0], np.diag(d[0]), *z[1:]))
            rows.append(parts)
        return rows


def _cauchy_weights(r: np.ndarray, k: float) -> np.ndarray:
    """Square roots of the Cauchy IRLS weights ``1 / (1 + (r/k)²)``: gross outliers
    lose their influence (it falls like 1/r) instead of keeping a constant one."""
    return 1.0 / np.sqrt(1.0 + (r / k) ** 2)


def _huber_weights(r: np.ndarray, k: float) -> np.ndarray:
    a = np.abs(r)
    return np.where(a <= k, 1.0, np.sqrt(k / np.maximum(a, 1e-300)))


def _solve(prob: _Problem, theta, root, s, radii, centers, free: str, max_nfev: int):
    """Solve for the blocks in ``free`` ("pose", "shape" or "all"); returns updated
    (theta, root, s, radii, centers, LM result)."""
    nf, n, G, M3 = len(prob.obs), prob.skel.n_dof, prob.skel.n_groups, radii.size
    cfg = prob.cfg
    pose_free = free in ("pose", "all")
    shape_free = free in ("shape", "all")
    C3 = M3 if (shape_free and cfg.free_centers) else 0
    G = G if (shape_free and cfg.fit_scales) else 0  # scale columns in the layout
    m_pose = nf * (n + 3) if pose_free else 0

    def unpack(x):
        th, rt, ss, rd, ce = theta, root, s, radii, centers
        if pose_free:
            th = x[: nf * n].reshape(nf, n)
            rt = x[nf * n : nf * (n + 3)].reshape(nf, 3)
        if shape_free:
            i = m_pose
            ss = x[i : i + G] if G else s
            rd = x[i + G : i + G + M3].reshape(radii.shape)
            if C3:
                ce = x[i + G + M3 : i + G + M3 + C3].reshape(centers.shape)
        return th, rt, ss, rd, ce

    x0 = []
    if pose_free:
        x0 += [theta.ravel(), root.ravel()]
    if shape_free:
        x0 += ([s] if G else []) + [radii.ravel()] + ([centers.ravel()] if C3 else [])
    x0 = np.concatenate(x0)
    cache = {}

    def system(x):
        key = x.tobytes()
        if key in cache:
            return cache[key]
        th, rt, ss, rd, ce = unpack(x)
        rows = prob.blocks(th, rt, ss, rd, ce, shape=shape_free)
        res, jac = [], []
        for f, parts in enumerate(rows):
            for _kind, r, Jt, Jr, Js, Jrad, Jc in parts:
                J = np.zeros((len(r), len(x)))
                if pose_free:
                    J[:, f * n : (f + 1) * n] = Jt
                    J[:, nf * n + 3 * f : nf * n + 3 * f + 3] = Jr
                if shape_free:
                    i = m_pose
                    if G:
                        J[:, i : i + G] = Js
                    J[:, i + G : i + G + M3] = Jrad
                    if C3:
                        J[:, i + G + M3 :] = Jc
                res.append(r)
                jac.append(J)
        if shape_free and cfg.shape_prior:
            i = m_pose
            w = 1.0 / cfg.sigma_radius
            res.append((rd.ravel() - prob.radii0.ravel()) * w)
            J = np.zeros((M3, len(x)))
            J[:, i + G : i + G + M3] = np.eye(M3) * w
            jac.append(J)
            if C3:
                w = 1.0 / cfg.sigma_center
                res.append((ce.ravel() - prob.centers0.ravel()) * w)
                J = np.zeros((C3, len(x)))
                J[:, i + G + M3 :] = np.eye(C3) * w
                jac.append(J)
        out = (np.concatenate(res), np.concatenate(jac, axis=0))
        cache.clear()
        cache[key] = out
        return out

    lo, hi = np.full(len(x0), -np.inf), np.full(len(x0), np.inf)
    if shape_free:
        lo[m_pose : m_pose + G] = 0.2
        lo[m_pose + G : m_pose + G + M3], hi[m_pose + G : m_pose + G + M3] = _radius_bounds(prob)
        if C3:
            lo[m_pose + G + M3 :], hi[m_pose + G + M3 :] = _center_bounds(prob)
    x = np.clip(x0, lo, hi)
    nfev = 0
    for _ in range(max(cfg.irls_rounds, 1)):  # weights frozen per round (IRLS)
        prob.freeze(*unpack(x))
        cache.clear()
        sol = levenberg_marquardt(system, x, lo, max_nfev, cfg.tol, hi=hi)
        nfev += sol.nfev
        moved = float(np.abs(sol.x - x).max(initial=0.0))
        x = sol.x
        if moved < cfg.irls_tol:
            break
    prob.frozen = None
    sol.nfev = nfev
    th, rt, ss, rd, ce = unpack(sol.x)
    return th, rt, ss, rd, ce, sol


def _radius_bounds(prob: _Problem) -> tuple[np.ndarray, np.ndarray]:
    """Bounds (3M,) of the radii: ``FitSettings.radius_ratio`` times the reference's."""
    r = np.asarray(prob.shape_ref.radii, float).ravel()
    a, b = prob.cfg.radius_ratio
    return np.maximum(a * r, 1e-3), b * r


def _center_bounds(prob: _Problem) -> tuple[np.ndarray, np.ndarray]:
    """Bounds (3M,) of the centres: the reference's ± ``center_shift`` × its ball's
    largest semi-axis, per coordinate."""
    ref = prob.shape_ref
    reach = prob.cfg.center_shift * np.asarray(ref.radii, float).max(axis=1, keepdims=True)
    c = np.asarray(ref.center0, float)
    return (c - reach).ravel(), (c + reach).ravel()


def fit(
    skel: Skeleton,
    balls: Metaballs,
    obs: Observations | list[Observations],
    theta0: np.ndarray,
    root0: np.ndarray,
    s0: np.ndarray,
    radii0: np.ndarray | None = None,
    solve: str = "alternate",
    settings: FitSettings | None = None,
    centers0: np.ndarray | None = None,
    shape_ref: Metaballs | None = None,
) -> FitResult | list[FitResult]:
    """Fit pose and/or shape to one frame's (or several frames') observations.

    Parameters
    ----------
    obs : Observations, or a list (one per frame) sharing the shape
    theta0 : (n,) or (F, n); root0 : (3,) or (F, 3); s0 : (G,); radii0 : (M, 3)
    centers0 : (M, 3) metaball centres in their bones' frames, metres before scaling
        (default ``balls.center0``); free in the shape solve when
        ``settings.free_centers``
    solve : ``"pose"`` (shape fixed), ``"shape"`` (pose fixed), ``"alternate"``
        (shape and pose in turn, ``settings.rounds`` times, then a joint polish when
        ``settings.polish``) or ``"all"`` (everything at once)
    shape_ref : the shape the radius and centre bounds are relative to (default
        ``balls``: its radii and centres); pass the template when ``balls`` carries an
        earlier solve's centres

    Returns
    -------
    FitResult, or a list of them (one per frame, same shape) when ``obs`` is a list.
    """
    cfg = settings or FitSettings()
    single = isinstance(obs, Observations)
    obs_l = [obs] if single else list(obs)
    nf = len(obs_l)
    theta = np.array(theta0, float).reshape(nf, skel.n_dof)
    root = np.array(root0, float).reshape(nf, 3)
    s = np.array(s0, float)
    radii = np.array(balls.radii if radii0 is None else radii0, float)
    centers = np.array(balls.center0 if centers0 is None else centers0, float)
    prob = _Problem(skel, balls, obs_l, cfg, radii.copy(), centers.copy(), shape_ref)
    steps = {
        "pose": ["pose"],
        "shape": ["shape"],
        "all": ["all"],
        "alternate": ["pose", "shape"] * cfg.rounds + (["all"] if cfg.polish else []),
    }
    if solve not in steps:
        raise ValueError(f"unknown solve mode {solve!r}")
    sol = None
    for step in steps[solve]:
        theta, root, s, radii, centers, sol = _solve(
            prob, theta, root, s, radii, centers, step, cfg.max_nfev
        )
    results = _report(prob, theta, root, s, radii, centers, sol)
    return results[0] if single else results


def _report(prob: _Problem, theta, root, s, radii, centers, sol) -> list[FitResult]:
    """Per-frame quality: attractor RMSE, σ of the angles (pose-only normal matrix)."""
    skel = prob.skel
    out = []
    rows = prob.blocks(theta, root, s, radii, centers, shape=False)
    for f, parts in enumerate(rows):
        rmse_field = rmse_m = np.nan
        if len(prob.gathers[f][0]):
            att = prob.attractors(f, theta, root, s, radii, centers)[2]
            rmse_field = float(np.sqrt(np.mean((att.L - LN_T) ** 2)))
            rmse_m = float(np.sqrt(np.mean(att.dist**2)))
        J = np.concatenate([np.concatenate([p[2], p[3]], axis=1) for p in parts], axis=0)
        r = np.concatenate([p[1] for p in parts])
        dof = max(len(r) - J.shape[1], 1)
        s0sq = float(r @ r) / dof
        N = J.T @ J
        try:
            cov = np.linalg.pinv(N, rcond=1e-12, hermitian=True) * max(s0sq, 1e-30)
            sig = np.sqrt(np.clip(np.diag(cov)[: skel.n_dof], 0, None))
        except np.linalg.LinAlgError:
            sig = np.full(skel.n_dof, np.nan)
        finite = bool(np.all(np.isfinite(theta[f])) and np.all(np.isfinite(root[f])))
        ok = bool(sol is not None and sol.status > 0 and finite)
        out.append(
            FitResult(
                theta=theta[f].copy(),
                root_xyz=root[f].copy(),
                s=s.copy(),
                radii=radii.copy(),
                centers=centers.copy(),
                rmse_field=rmse_field,
                rmse_m=rmse_m,
                theta_sigma=sig,
                converged=ok,
                diverged=not finite,
                message="" if sol is None else sol.message,
                nfev=0 if sol is None else int(sol.nfev),
            )
        )
    return out
