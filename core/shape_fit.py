"""Body shape from dense surface points: metaball radii and centres with the pose held.

The shape step of paper 1 (§4, eq. 15) solves the metaball radii so that every 3-D
surface point ``x`` lies on the body surface ``Σ f_m(x) = 0.5``.  Here that is done
for the *whole-body* surface — the iso-surface that is rendered, measured and built
in Blender — over the points of several frames at once (poses held, e.g. from the
pose fit or the truth), by weighted least squares on two observation types and a
prior:

* **data points** (eq. 15): the signed distance ``e(x) = (ln Σ f − ln 0.5)/|∇ ln Σ f|``
  of each observed point to the surface (:mod:`core.attractor`), over its σ, with
  Cauchy re-weighting against outliers.  The sum runs over the ``k_members`` metaballs
  of strongest field at the point (the far ones add nothing measurable);
* **model points** (the penalty against bulging where there are no points): points
  sampled on the current model surface that the cameras see (z-buffered against the
  model's own rendering, :func:`core.model_render.render_parts`, in ``min_views``
  cameras, as the data points were) must not lie outside the data: with ``o`` the
  median normal offset ``n·(x_s − y)`` of the nearest data points ``y``, a point with
  ``o > gate`` gets the residual ``e(x_s) + o − gate`` — zero when the surface has
  moved inward along its normal ``n`` to within the gate of the data.  The gate
  (1 cm) absorbs what the point spacing explains on a curved surface (data points
  2 cm aside lie 4 mm below the tangent plane of a 5 cm limb), which a two-sided term
  would turn into a systematic shrinking.  A metaball growing into space where the
  cameras see nothing is pulled back; a region no camera sees is left to the
  symmetry and the prior.  In a frame whose silhouettes hold the outline, the excess
  ``o − gate`` is Cauchy-weighted (knee ``model_robust_scale · σ_model``, 12 mm): a
  seen surface with no tracked point near it is as often a gap in the points (tracks
  lost, weak texture) as a bulge, and fully weighted such gaps pulled the trunk in
  across them;
* **symmetry** (soft, ``σ_symmetry``): a left metaball and its right partner have the
  same radii and mirror-image centres (about the skeleton's rest-pose sagittal plane),
  and a metaball of the trunk or head is centred on that plane.  The studio's
  ``line3`` rig sees the walker's right side in no frame: without this its shape is
  left to the prior.  Opt-in (``σ_one_sided`` > 0): where a pair's or a mid-plane
  metaball's data points lie on one side only (:func:`core.shape_priors.one_sided`)
  it is held at that tighter σ.  At ``σ_symmetry`` a trunk metaball can drift towards
  the seen side while its radius shrinks, which keeps the seen surface and thins the
  unseen one (jumps_line3: the trunk's right side 17-20 mm inside the true mesh); held,
  it cannot follow a skeleton that itself sits off in depth, so the tighter σ helps
  only where the skeleton is well placed (``docs/design.md``, "The side no point
  sees");
* **smoothness** (``σ_smooth``): neighbouring metaballs — consecutive on one bone, and
  across a joint — change alike from the start shape (radii and centre
  displacements), so a limb's or the trunk's cross-section varies smoothly instead of
  alternating tiny and large metaballs that blend into the same surface where it is
  seen (the overlapping trunk metaballs otherwise trade their widths round after
  round);
* **prior** towards the start shape (the template): ``(radii − radii0)/σ_radius``,
  ``(centres − centres0)/σ_center``.

The symmetry and smoothness rows are in :mod:`core.shape_priors`, the residuals and
Jacobian of the whole problem in :mod:`core.shape_problem` (:class:`ShapeProblem`), the
settings in :mod:`core.shape_settings` (:class:`ShapeSettings`); both re-exported here.

Unknowns: radii (M, 3) and, when ``free_centers``, the centres (M, 3) in their bones'
frames (metres before scaling).  Levenberg–Marquardt on the normal equations
(:func:`core.lm_solver.levenberg_marquardt`) inside re-weighting rounds: each round
re-selects the members, re-samples the model points (same directions every round)
and re-tests them, and freezes the weights, so the Jacobian within a round is exact.

Arrays: ``xyz`` (N, 3) world metres; ``theta`` (F, n) radians; ``root_xyz`` (F, 3)
metres; ``s`` (G,) bone scales.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .attractor import attractor
from .camera import Camera
from .lm_solver import levenberg_marquardt
from .metaballs import Metaballs
from .shape_priors import mirror_pairs  # noqa: F401  (re-exported)
from .shape_problem import (
    ShapeProblem,
    model_offsets,  # noqa: F401  (re-exported)
    nearest_members,  # noqa: F401  (re-exported)
    seen_by,  # noqa: F401  (re-exported)
)
from .shape_settings import ShapeSettings
from .skeleton import Skeleton, forward


@dataclass
class ShapeFit:
    """Result of :func:`fit_shape`.

    Attributes
    ----------
    metaballs : the fitted metaballs (radii, and centres when free)
    rms_m : (F,) RMS distance of each frame's data points to the surface (Cauchy
        inliers, i.e. within the last round's knee), NaN for a frame left out
    model_rms_m : (F,) RMS normal offset of the seen model points to the data
    silhouette_rms_px : (F,) RMS of the silhouette contour pairs (with ``contours``)
    n_points : (F,) data points used; n_model : (F,) seen model points
    frame_ok : (F,) False for a frame left out (too few points)
    converged : the last round moved no unknown by more than ``round_tol`` or changed
        the cost by less than ``cost_tol`` (moves along nearly flat directions, e.g.
        overlapping metaballs trading widths, hardly change the surface)
    message : what happened, in words
    """

    metaballs: Metaballs
    rms_m: np.ndarray
    model_rms_m: np.ndarray
    n_points: np.ndarray
    n_model: np.ndarray
    frame_ok: np.ndarray
    converged: bool
    message: str
    #: (F,) RMS of each frame's silhouette contour pairs at the last freeze [px] (NaN: none)
    silhouette_rms_px: np.ndarray | None = None


def fit_shape(
    skel: Skeleton,
    balls: Metaballs,
    s: np.ndarray,
    theta: np.ndarray,
    root_xyz: np.ndarray,
    points: list[np.ndarray],
    cameras: list[Camera] | None = None,
    sigma: list[np.ndarray] | None = None,
    settings: ShapeSettings | None = None,
    seed: int = 0,
    progress=None,
    contours: list | None = None,
    rays=None,
    parts: list | None = None,
) -> ShapeFit:
    """Fit the metaball radii (and centres) to surface points of F frames, pose held.

    Parameters
    ----------
    skel, balls, s : the body; ``balls`` is the start (and prior) shape
    theta : (F, n) radians; root_xyz : (F, 3) metres — the held poses
    points : list (F) of (N_f, 3) surface points, world metres (outliers allowed)
    cameras : the scene's cameras, for the model-point penalty (without them only the
        data points, the symmetry and the prior act)
    sigma : list (F) of (N_f,) a-priori σ of the points, metres (default
        ``settings.sigma_point``)
    seed : seeds the model points' sampling
    contours : list (F) of list (C) of list of :class:`core.contours.Contour`, optional
        Each frame's observed occluding contours in ``cameras``: the blended surface's
        outline is fitted to them too (σ ``settings.sigma_silhouette_px``), so the shape
        follows the silhouettes where no point lies (the back of a body the cameras see
        from one side).  A frame with contours needs no points.
    rays : list (C) of (H, W, 3) cached viewing rays (:func:`core.model_render.camera_rays`)
    parts : list (F) of (B,) bool or None, optional
        The body parts (bones) whose silhouette pairs and model points (the penalty
        against bulging) count in each frame — those whose pose the frame measured; a
        part posed by inference (hidden, mirrored, bridged) would teach the shape its
        pose error.  None: every part.
    progress : callable ``(round, rounds)``, optional
        Called before every re-weighting round (a :class:`core.progress.Progress`
        wrapper raises there when the user cancels).

    Returns
    -------
    ShapeFit — a frame with fewer than ``min_points`` finite points is left out and
    flagged; with no usable frame the start shape is returned, flagged.
    """
    cfg = settings or ShapeSettings()
    theta = np.atleast_2d(np.asarray(theta, float))
    root_xyz = np.asarray(root_xyz, float).reshape(-1, 3)
    nf = len(points)
    if theta.shape != (nf, skel.n_dof) or root_xyz.shape != (nf, 3):
        raise ValueError(
            f"{nf} frames of points need theta ({nf}, {skel.n_dof}) and "
            f"root_xyz ({nf}, 3), got {theta.shape} and {root_xyz.shape}"
        )
    s = np.asarray(s, float)
    use_sil = contours is not None and cameras is not None and cfg.sigma_silhouette_px > 0
    if use_sil and len(contours) != nf:
        raise ValueError(f"{nf} frames of points need {nf} frames of contours, got {len(contours)}")
    keep, poses, xyzs, sigs, sil = np.zeros(nf, bool), [], [], [], []
    for f in range(nf):
        xyz = np.asarray(points[f], float).reshape(-1, 3)
        sig = (
            np.full(len(xyz), cfg.sigma_point)
            if sigma is None
            else np.broadcast_to(np.asarray(sigma[f], float), (len(xyz),)).copy()
        )
        good = np.all(np.isfinite(xyz), axis=1) & np.isfinite(sig) & (sig > 0)
        outline = use_sil and contours[f] is not None and any(len(c) for c in contours[f])
        if good.sum() < cfg.min_points:
            if not outline:
                continue
            good[:] = False  # too few points to weigh: the silhouettes alone
        keep[f] = True
        poses.append(forward(skel, theta[f][None], root_xyz[f][None], s))
        xyzs.append(xyz[good])
        sigs.append(sig[good])
        sil.append(
            (
                theta[f],
                root_xyz[f],
                contours[f] if outline else None,
                None if parts is None else parts[f],
            )
        )
    nan = np.full(nf, np.nan)
    if not keep.any():
        return ShapeFit(
            balls.copy(),
            nan,
            nan.copy(),
            np.zeros(nf, int),
            np.zeros(nf, int),
            keep,
            False,
            "no frame has enough points"
            + (" or silhouettes" if use_sil else "")
            + ": the start shape is kept",
            nan.copy(),
        )
    use_cams = (
        cameras
        if (cfg.model_points and cameras is not None and len(cameras) >= cfg.min_views)
        else None
    )
    prob = ShapeProblem(
        skel,
        balls,
        s,
        poses,
        xyzs,
        sigs,
        use_cams,
        cfg,
        seed,
        silhouettes=(cameras, rays, sil) if use_sil else None,
    )
    x = prob.pack(prob.radii0, prob.centers0)
    lo, hi = np.full(len(x), -np.inf), np.full(len(x), np.inf)
    lo[: 3 * prob.M] = cfg.min_radius
    if cfg.radius_ratio > 0:
        r0 = prob.radii0.ravel()
        lo[: 3 * prob.M] = np.maximum(cfg.min_radius, r0 / cfg.radius_ratio)
        hi[: 3 * prob.M] = np.maximum(r0 * cfg.radius_ratio, lo[: 3 * prob.M])
    x = np.clip(x, lo, hi)
    converged, moved, cost, change = False, np.inf, np.inf, np.inf
    for k in range(cfg.rounds):
        if progress is not None:
            progress(k, cfg.rounds)
        prob.freeze(x)
        sol = levenberg_marquardt(prob.system, x, lo, cfg.max_nfev, cfg.tol, max_step=0.02, hi=hi)
        moved = float(np.abs(sol.x - x).max(initial=0.0))

        change = abs(cost - sol.cost) / max(sol.cost, 1e-300) if np.isfinite(cost) else np.inf
        x, cost = sol.x, sol.cost
        if moved < cfg.round_tol or change < cfg.cost_tol:
            converged = True
            break
    msg = (
        "converged"
        if converged
        else (
            f"not converged in {cfg.rounds} rounds (the last changed the cost by "
            f"{100 * change:.1f} %, moved an unknown by {1e3 * moved:.1f} mm)"
        )
    )
    radii, centers = prob.unpack(x)
    out = balls.copy().with_parts(np.array(centers, float), np.array(radii, float))
    prob.freeze(x)
    rms, mrms = nan.copy(), nan.copy()
    n_pts, n_mod = np.zeros(nf, int), np.zeros(nf, int)
    srms = nan.copy()
    for f, fr in zip(np.flatnonzero(keep), prob.frames, strict=True):
        srms[f] = fr.sil_rms
        if not len(fr.xyz):
            continue
        _, Rw, cw = prob.geometry(fr, radii, centers)
        dist = attractor(fr.xyz, fr.idx, fr.valid, Rw, cw, radii).dist
        inl = np.abs(dist) <= fr.knee
        rms[f] = float(np.sqrt(np.mean(dist[inl] ** 2))) if inl.any() else np.nan
        n_pts[f] = len(fr.xyz)
        if fr.soff_all is not None:
            mrms[f] = float(np.sqrt(np.mean(fr.soff_all**2)))
            n_mod[f] = len(fr.soff_all)
    if prob.one_sided is not None and any(f.any() for f in prob.one_sided):
        pairs, centres = prob.one_sided
        msg += (
            f"; {int(pairs.sum())} of {len(pairs)} left/right pairs and {int(centres.sum())} "
            f"of {len(centres)} mid-plane metaballs had their points on one side, held "
            f"symmetric at {1e3 * cfg.sigma_one_sided:g} mm"
        )
    if not keep.all():
        msg += f"; {int((~keep).sum())} frame(s) with fewer than {cfg.min_points} points left out"
    return ShapeFit(out, rms, mrms, n_pts, n_mod, keep, converged, msg, srms)
