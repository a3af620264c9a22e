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
  symmetry and the prior;
* **symmetry** (soft, ``σ_symmetry``): a left metaball and its right partner have the
  same radii and mirror-image centres (about the skeleton's rest-pose sagittal plane),
  and a metaball of the trunk or head is centred on that plane.  The studio's
  ``line3`` rig sees the walker's right side in no frame: without this its shape is
  left to the prior;
* **smoothness** (``σ_smooth``): neighbouring metaballs — consecutive on one bone, and
  across a joint — change alike from the start shape (radii and centre
  displacements), so a limb's or the trunk's cross-section varies smoothly instead of
  alternating tiny and large metaballs that blend into the same surface where it is
  seen (the overlapping trunk metaballs otherwise trade their widths round after
  round);
* **prior** towards the start shape (the template): ``(radii − radii0)/σ_radius``,
  ``(centres − centres0)/σ_center``.

The symmetry and smoothness rows are in :mod:`core.shape_priors`.

Unknowns: radii (M, 3) and, when ``free_centers``, the centres (M, 3) in their bones'
frames (metres before scaling).  Levenberg–Marquardt on the normal equations
(:func:`core.fitting._levenberg_marquardt`) inside re-weighting rounds: each round
re-selects the members, re-samples the model points (same directions every round)
and re-tests them, and freezes the weights, so the Jacobian within a round is exact.

Arrays: ``xyz`` (N, 3) world metres; ``theta`` (F, n) radians; ``root_xyz`` (F, 3)
metres; ``s`` (G,) bone scales.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .attractor import LN_T, attractor, attractor_jacobians, scatter
from .camera import Camera
from .fitting import _levenberg_marquardt
from .metaballs import Metaballs, local_coords, sample_surface, world_frames
from .model_render import render_parts
from .shape_priors import chain_pairs, mirror_pairs, smooth_rows, symmetry_rows
from .skeleton import Skeleton, bone_frames, forward


@dataclass
class ShapeSettings:
    """Weights and solver settings of :func:`fit_shape` (lengths in metres)."""

    sigma_point: float = 0.003  # σ of a data point's distance (when none is given)
    sigma_model: float = 0.004  # σ of a seen model point's distance to the data
    sigma_radius: float = 0.03  # prior towards the start radii
    sigma_center: float = 0.02  # prior towards the start centres
    sigma_symmetry: float = 0.003  # left/right symmetry of radii and centres (0: off)
    sigma_smooth: float = 0.01  # neighbours along a bone: radii and displacements (0: off)
    free_centers: bool = True
    model_points: bool = True  # the penalty against bulging (needs cameras)
    k_members: int = 8  # metaballs in a point's field
    samples_per_ball: int = 40  # model points drawn per metaball and frame
    min_views: int = 2  # cameras that must see a model point
    depth_tol: float = 0.02  # z-buffer tolerance of the model points
    neighbours: int = 5  # data points whose median normal offset a model point uses
    max_offset: float = 0.05  # cap of a model point's offset
    model_gate: float = 0.01  # offsets below this are no bulge (curvature, point spacing)
    robust_scale: float = 3.0  # Cauchy knee of the data points, in σ
    rounds: int = 10
    max_nfev: int = 15
    tol: float = 1e-4
    round_tol: float = 2e-4  # converged when no radius or centre moved more than this
    cost_tol: float = 0.01  # ... or the cost changed by less than this share in a round
    min_radius: float = 0.005
    #: every radius stays within [start / ratio, start · ratio] (0: only ``min_radius``):
    #: overlapping metaballs can trade widths along nearly flat directions of the cost,
    #: and left free some collapse into needles while a neighbour swells
    radius_ratio: float = 2.0
    min_points: int = 20  # a frame with fewer data points is left out (flagged)
    #: σ of a silhouette contour pair of the blended surface [px] (0: off; needs the
    #: frames' contours, :func:`fit_shape` ``contours``)
    sigma_silhouette_px: float = 1.0
    huber_silhouette_px: float = 3.0  # Huber knee of those pairs [px]
    max_dist_silhouette_px: float = 12.0  # largest rim ↔ contour pairing distance [px]


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


def nearest_members(
    xyz: np.ndarray, Rw: np.ndarray, cw: np.ndarray, radii: np.ndarray, k: int
) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` metaballs of strongest field at each point.

    Parameters
    ----------
    xyz : (N, 3) world points; Rw (M, 3, 3), cw (M, 3), radii (M, 3) metaball frames

    Returns
    -------
    idx : (N, K) int metaball indices, K = min(k, M); valid : (N, K) bool (all True)
    """
    y = local_coords(xyz, Rw, cw)
    d = np.sum((y / radii[None]) ** 2, axis=-1)  # (N, M)
    k = min(int(k), len(radii))
    idx = (
        np.argpartition(d, k - 1, axis=1)[:, :k]
        if k < len(radii)
        else np.broadcast_to(np.arange(len(radii)), d.shape).copy()
    )
    return idx, np.ones(idx.shape, bool)


def seen_by(
    cameras: list[Camera],
    xyz: np.ndarray,
    Rw: np.ndarray,
    cw: np.ndarray,
    visible: np.ndarray,
    bone: np.ndarray,
    depth_tol: float,
) -> np.ndarray:
    """How many cameras see each point of the model surface (N,) int.

    A point is seen when it projects into the image and lies no farther than
    ``depth_tol`` metres behind the model's own rendering there (the rendered
    ellipsoids, semi-axes ``visible`` (M, 3), of :func:`core.model_render.render_parts`).
    """
    views = np.zeros(len(xyz), int)
    for cam in cameras:
        w, h = cam.size
        ren = render_parts(cam, cw, Rw, visible, bone)
        with np.errstate(all="ignore"):
            uv = cam.project(xyz)
        ok = np.all(np.isfinite(uv), axis=1)
        iu = np.round(np.where(ok, uv[:, 0], -1)).astype(int)
        iv = np.round(np.where(ok, uv[:, 1], -1)).astype(int)
        ok &= (iu >= 0) & (iu < w) & (iv >= 0) & (iv < h)
        depth = np.linalg.norm(xyz - cam.center, axis=1)
        zb = ren.depth[np.clip(iv, 0, h - 1), np.clip(iu, 0, w - 1)]
        views += ok & (depth <= zb + depth_tol)
    return views


class _Frame:
    """One frame's data and model points, with the weights frozen for a round."""

    def __init__(self, pose, xyz, sigma, theta=None, root=None, contours=None, parts=None):
        self.pose, self.xyz, self.sigma = pose, xyz, sigma
        self.theta, self.root, self.contours, self.parts = theta, root, contours, parts
        self.idx = self.valid = self.w = None
        self.knee = np.inf
        self.xs = self.sidx = self.svalid = self.soff = self.sinv = None
        self.soff_all = None
        self.sil = None  # silhouette rows linearised at the round's start: (r0, J, x0, w)
        self.sil_rms = np.nan


def _cauchy(r: np.ndarray, c: float) -> np.ndarray:
    """Square roots of the Cauchy IRLS weights ``1 / (1 + (r/c)²)``."""
    return 1.0 / np.sqrt(1.0 + (r / c) ** 2)


class ShapeProblem:
    """Residuals and Jacobian of the shape fit (the unknowns packed as ``x``).

    ``x`` = radii (3M) then, when ``free_centers``, centres (3M).  :meth:`freeze`
    fixes the members, weights and model points at a given ``x``; :meth:`system`
    returns the residual vector and its exact Jacobian for those frozen choices.
    """

    def __init__(
        self,
        skel: Skeleton,
        balls: Metaballs,
        s: np.ndarray,
        poses: list,
        points: list[np.ndarray],
        sigma: list[np.ndarray],
        cameras: list[Camera] | None,
        cfg: ShapeSettings,
        seed: int = 0,
        silhouettes=None,
    ):
        self.skel, self.balls, self.s, self.cfg = skel, balls, np.asarray(s, float), cfg
        self.cameras = cameras
        self.anc = skel.ancestors()
        self.M = len(balls)
        self.n_c = 3 * self.M if cfg.free_centers else 0
        self.radii0, self.centers0 = balls.radii.copy(), balls.center0.copy()
        # silhouettes: (cameras, rays, [(theta (n,), root (3,), contours per camera,
        # parts (B,) bool or None)] per frame)
        self.sil_cameras, self.sil_rays, sil = silhouettes or (None, None, None)
        sil = sil or [(None, None, None, None)] * len(poses)
        self.frames = [
            _Frame(p, x, sg, *c) for p, x, sg, c in zip(poses, points, sigma, sil, strict=True)
        ]
        self.sym = mirror_pairs(skel, balls, s) if cfg.sigma_symmetry > 0 else None
        self.chain = chain_pairs(balls, skel) if cfg.sigma_smooth > 0 else None
        self.seed = int(seed)

    def pack(self, radii: np.ndarray, centers: np.ndarray) -> np.ndarray:
        return np.concatenate([np.ravel(radii)] + ([np.ravel(centers)] if self.n_c else []))

    def unpack(self, x: np.ndarray):
        """``(radii (M, 3), centres (M, 3))`` of a packed vector."""
        radii = x[: 3 * self.M].reshape(self.M, 3)
        centers = x[3 * self.M :].reshape(self.M, 3) if self.n_c else self.centers0
        return radii, centers

    def geometry(self, fr: _Frame, radii, centers):
        b = self.balls.with_parts(centers, radii)
        Rw, cw = world_frames(self.skel, fr.pose, b, self.s)
        return b, Rw[0], cw[0]

    def freeze(self, x: np.ndarray) -> None:
        """Per frame: members, Cauchy weights of the data points, and the seen model
        points with their normal offsets to the data, at ``x``."""
        cfg = self.cfg
        radii, centers = self.unpack(x)
        for k, fr in enumerate(self.frames):
            b, Rw, cw = self.geometry(fr, radii, centers)
            self._freeze_silhouette(fr, b, x)
            if not len(fr.xyz):  # silhouettes only
                fr.xs = fr.soff_all = None
                continue
            fr.idx, fr.valid = nearest_members(fr.xyz, Rw, cw, radii, cfg.k_members)
            att = attractor(fr.xyz, fr.idx, fr.valid, Rw, cw, radii)
            dist = np.where(np.isfinite(att.dist), att.dist, 1.0)
            mad = 1.4826 * float(np.median(np.abs(dist - np.median(dist))))
            fr.knee = max(cfg.robust_scale * float(np.median(fr.sigma)), 3.0 * mad)
            fr.w = att.inv_g / fr.sigma * _cauchy(dist, fr.knee)
            fr.xs = fr.soff_all = None
            if self.cameras is None:
                continue
            xs, ok = sample_surface(
                self.skel, fr.pose, b, self.s, per_ball=cfg.samples_per_ball, seed=self.seed + k
            )  # same directions every round
            if fr.parts is not None:  # no penalty on a part the frame did not measure
                owner = np.repeat(np.arange(self.M), cfg.samples_per_ball)
                ok &= np.asarray(fr.parts, bool)[b.bone[owner]]
            xs = xs[ok]
            seen = seen_by(self.cameras, xs, Rw, cw, b.visible, b.bone, cfg.depth_tol)
            xs = xs[seen >= cfg.min_views]
            if not len(xs):
                continue
            sidx, svalid = nearest_members(xs, Rw, cw, radii, cfg.k_members)
            satt = attractor(xs, sidx, svalid, Rw, cw, radii)
            off = model_offsets(xs, -satt.grad, fr.xyz, cfg.neighbours, cfg.max_offset)
            fr.soff_all = off
            bulge = off > cfg.model_gate
            if not bulge.any():
                continue
            fr.xs, fr.sidx, fr.svalid = xs[bulge], sidx[bulge], svalid[bulge]
            fr.soff = off[bulge] - cfg.model_gate
            fr.sinv = satt.inv_g[bulge]

    def _freeze_silhouette(self, fr: _Frame, b: Metaballs, x: np.ndarray) -> None:
        """Pair the blended surface's rim with the frame's image contours and linearise.

        The whole-body surface ``Σ f = 0.5`` is rendered as the ellipsoids that follow it
        (:func:`core.metaballs.render_radii`, their ratio to the radii held for the
        round); its occluding contour is paired with the observed one in every camera
        (:func:`core.contour_obs.contour_observations`, all cameras fused) and the
        residuals (pixels, along the image normal) are linearised in the radii and the
        centres: ``r(x) ≈ r0 + J (x − x0)``, Huber-weighted at ``r0``.
        """
        from .contour_obs import contour_observations
        from .metaballs import render_radii

        cfg = self.cfg
        fr.sil, fr.sil_rms = None, np.nan
        if fr.contours is None or self.sil_cameras is None or cfg.sigma_silhouette_px <= 0:
            return
        vis = render_radii(self.skel, fr.pose, b, self.s)
        bv = b.copy()
        bv.visible_scale = vis / b.radii
        obs = contour_observations(
            self.skel,
            fr.theta,
            fr.root,
            self.s,
            bv,
            self.sil_cameras,
            fr.contours,
            sigma_px=cfg.sigma_silhouette_px,
            max_dist_px=cfg.max_dist_silhouette_px,
            select=False,
            rays=self.sil_rays,
        )
        keep = (
            np.ones(len(obs), bool) if fr.parts is None else np.asarray(fr.parts, bool)[obs.part]
        )  # parts a measurement placed, only
        if not keep.any():
            return
        M = self.M
        e = obs.ellipsoid[keep]
        J = np.zeros((len(e), 3 * M + self.n_c))
        np.put_along_axis(J, 3 * e[:, None] + np.arange(3)[None], obs.J_radii[keep], axis=1)
        if self.n_c:  # a centre moves its ellipsoid's rim rigidly: the root's Jacobian
            Rb, _ = bone_frames(self.skel, fr.pose)
            scale = np.where(b.group >= 0, self.s[np.maximum(b.group, 0)], 1.0)
            Jc = np.einsum("mj,mjk->mk", obs.J_root[keep], Rb[0, b.bone[e]]) * scale[e, None]
            np.put_along_axis(J, 3 * M + 3 * e[:, None] + np.arange(3)[None], Jc, axis=1)
        r0 = np.asarray(obs.residual, float)[keep]
        a = np.abs(r0)
        k = cfg.huber_silhouette_px
        w = np.sqrt(np.where(a <= k, 1.0, k / np.maximum(a, 1e-12))) / cfg.sigma_silhouette_px
        fr.sil = (r0, J, x.copy(), w)
        fr.sil_rms = float(np.sqrt(np.mean(r0**2)))

    def _rows(self, fr, b, Rw, cw, radii, x, idx, valid, w, off=None):
        att = attractor(x, idx, valid, Rw, cw, radii)
        jac = attractor_jacobians(
            self.skel, fr.pose, b, self.s, x, idx, att, radii, self.anc, shape=True
        )
        e = att.L - LN_T
        scale = w if off is None else w * off[1]
        r = e * scale if off is None else (e * off[1] + off[0]) * w
        J = [scatter(jac[3], idx, valid, self.M) * scale[:, None]]
        if self.n_c:
            J.append(scatter(jac[4], idx, valid, self.M) * scale[:, None])
        return r, np.concatenate(J, axis=1)

    def system(self, x: np.ndarray):
        """Residuals (m,) and Jacobian (m, len(x)) at ``x`` (weights as frozen)."""
        cfg, M, n_c = self.cfg, self.M, self.n_c
        radii, centers = self.unpack(x)
        res, jac = [], []
        for fr in self.frames:
            b, Rw, cw = self.geometry(fr, radii, centers)
            if len(fr.xyz):
                r, J = self._rows(fr, b, Rw, cw, radii, fr.xyz, fr.idx, fr.valid, fr.w)
                res.append(r)
                jac.append(J)
            if fr.xs is not None:
                r, J = self._rows(
                    fr,
                    b,
                    Rw,
                    cw,
                    radii,
                    fr.xs,
                    fr.sidx,
                    fr.svalid,
                    np.full(len(fr.xs), 1.0 / cfg.sigma_model),
                    off=(fr.soff, fr.sinv),
                )
                res.append(r)
                jac.append(J)
            if fr.sil is not None:
                r0, J, x0, w = fr.sil
                res.append((r0 + J @ (x - x0)) * w)
                jac.append(J * w[:, None])
        w = 1.0 / cfg.sigma_radius
        res.append((radii - self.radii0).ravel() * w)
        jac.append(np.hstack([np.eye(3 * M) * w, np.zeros((3 * M, n_c))]))
        if n_c:
            w = 1.0 / cfg.sigma_center
            res.append((centers - self.centers0).ravel() * w)
            jac.append(np.hstack([np.zeros((n_c, 3 * M)), np.eye(n_c) * w]))
        if self.sym is not None:
            r, J = symmetry_rows(self.sym, M, n_c, 1.0 / cfg.sigma_symmetry, radii, centers)
            res.append(r)
            jac.append(J)
        if self.chain is not None and len(self.chain):
            r, J = smooth_rows(
                self.chain,
                M,
                n_c,
                1.0 / cfg.sigma_smooth,
                radii,
                centers,
                self.radii0,
                self.centers0,
            )
            res.append(r)
            jac.append(J)
        return np.concatenate(res), np.concatenate(jac, axis=0)


def model_offsets(
    xs: np.ndarray, outward: np.ndarray, data: np.ndarray, k: int, cap: float
) -> np.ndarray:
    """Signed offsets (S,) of model surface points from the data along their normals.

    Parameters
    ----------
    xs : (S, 3) model surface points; outward : (S, 3) outward directions (any length)
    data : (N, 3) observed points; k : nearest data points whose median is taken
    cap : offsets are clipped to ``[-cap, cap]`` metres

    Returns
    -------
    (S,) metres, positive where the model surface lies outside the data.
    """
    n = outward / np.maximum(np.linalg.norm(outward, axis=1, keepdims=True), 1e-12)
    k = max(1, min(int(k), len(data)))
    _, nb = cKDTree(data).query(xs, k=k)
    nb = np.asarray(nb).reshape(len(xs), k)
    off = np.median(np.einsum("nki,ni->nk", xs[:, None, :] - data[nb], n), axis=1)
    return np.clip(off, -cap, cap)


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
        sol = _levenberg_marquardt(prob.system, x, lo, cfg.max_nfev, cfg.tol, max_step=0.02, hi=hi)
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
    if not keep.all():
        msg += f"; {int((~keep).sum())} frame(s) with fewer than {cfg.min_points} points left out"
    return ShapeFit(out, rms, mrms, n_pts, n_mod, keep, converged, msg, srms)
