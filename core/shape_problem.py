"""The least-squares problem of the whole-body shape fit: residuals and exact Jacobian.

:class:`ShapeProblem` packs the unknowns ``x`` — radii (3M) then, when
``free_centers``, centres (3M) in their bones' frames (metres before scaling) — and for
weights frozen once per re-weighting round (:meth:`ShapeProblem.freeze`) returns the
residuals and the Jacobian (:meth:`ShapeProblem.system`) of the observation types and
priors that :mod:`core.shape_fit` describes: data points, seen model points, silhouette
pairs, symmetry, smoothness and the prior towards the start shape.  Its helpers pick a
point's strongest metaballs (:func:`nearest_members`), count the cameras that see a
model surface point (:func:`seen_by`) and measure the model points' normal offsets
from the data (:func:`model_offsets`).  All are re-exported by :mod:`core.shape_fit`.

Arrays: ``xyz`` (N, 3) world metres; metaball frames ``Rw`` (M, 3, 3), ``cw`` (M, 3),
radii (M, 3) metres; ``s`` (G,) bone scales.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

from .attractor import LN_T, attractor, attractor_jacobians
from .camera import Camera
from .metaball_surface import sample_surface
from .metaballs import Metaballs, local_coords, world_frames
from .model_render import render_parts
from .shape_priors import chain_pairs, mirror_pairs, one_sided, smooth_rows, symmetry_rows
from .shape_settings import ShapeSettings
from .skeleton import Skeleton, bone_frames


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
        self.xs = self.sidx = self.svalid = self.soff = self.sinv = self.sw = None
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
        self.sym_w = self.one_sided = None
        if self.sym is not None:
            pairs = np.zeros(len(self.sym.left), bool)
            centres = np.zeros(len(self.sym.centre), bool)
            if cfg.sigma_one_sided > 0 and cfg.one_sided_ratio > 0:
                pairs, centres = one_sided(
                    self.sym, skel, balls, s, poses, points, cfg.one_sided_ratio
                )
            self.one_sided = (pairs, centres)
            w_one = 1.0 / (cfg.sigma_one_sided or cfg.sigma_symmetry)
            self.sym_w = tuple(
                np.where(f, w_one, 1.0 / cfg.sigma_symmetry) for f in (pairs, centres)
            )
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
            fr.sw = np.full(len(fr.soff), 1.0 / cfg.sigma_model)
            if cfg.model_robust_scale > 0 and fr.sil is not None:
                # the silhouettes hold the outline: a large offset is as likely a gap
                fr.sw *= _cauchy(fr.soff, cfg.model_robust_scale * cfg.sigma_model)

    def _freeze_silhouette(self, fr: _Frame, b: Metaballs, x: np.ndarray) -> None:
        """Pair the blended surface's rim with the frame's image contours and linearise.

        The whole-body surface ``Σ f = 0.5`` is rendered as the ellipsoids that follow it
        (:func:`core.metaball_surface.render_radii`, their ratio to the radii held for the
        round); its occluding contour is paired with the observed one in every camera
        (:func:`core.contour_obs.contour_observations`, all cameras fused) and the
        residuals (pixels, along the image normal) are linearised in the radii and the
        centres: ``r(x) ≈ r0 + J (x − x0)``, Huber-weighted at ``r0``.
        """
        from .contour_obs import contour_observations
        from .metaball_surface import render_radii

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
        fr.sil = (r0, sparse.csr_matrix(J), x.copy(), w)
        fr.sil_rms = float(np.sqrt(np.mean(r0**2)))

    def _rows(self, fr, b, Rw, cw, radii, x, idx, valid, w, off=None):
        att = attractor(x, idx, valid, Rw, cw, radii)
        jac = attractor_jacobians(
            self.skel, fr.pose, b, self.s, x, idx, att, radii, self.anc, shape=True
        )
        e = att.L - LN_T
        scale = w if off is None else w * off[1]
        r = e * scale if off is None else (e * off[1] + off[0]) * w
        blocks = [jac[3]] + ([jac[4]] if self.n_c else [])
        return r, member_rows(blocks, idx, valid, scale, self.M)

    def system(self, x: np.ndarray):
        """Residuals (m,) and Jacobian (m, len(x)) at ``x`` (weights as frozen).

        The Jacobian is a ``scipy.sparse`` CSR matrix: a data point's row touches only
        its few member metaballs (on make demo's walk 22k rows by 504 unknowns, 7 %
        filled); :func:`core.lm_solver.levenberg_marquardt` forms ``JᵀJ`` from it.
        """
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
                    fr.sw,
                    off=(fr.soff, fr.sinv),
                )
                res.append(r)
                jac.append(J)
            if fr.sil is not None:
                r0, J, x0, w = fr.sil
                res.append((r0 + J @ (x - x0)) * w)
                jac.append(sparse.diags(w) @ J)
        n_x = 3 * M + n_c
        w = 1.0 / cfg.sigma_radius
        res.append((radii - self.radii0).ravel() * w)
        jac.append(sparse.eye(3 * M, n_x, format="csr") * w)
        if n_c:
            w = 1.0 / cfg.sigma_center
            res.append((centers - self.centers0).ravel() * w)
            jac.append(sparse.eye(n_c, n_x, k=3 * M, format="csr") * w)
        if self.sym is not None:
            r, J = symmetry_rows(self.sym, M, n_c, self.sym_w[0], radii, centers, self.sym_w[1])
            res.append(r)
            jac.append(sparse.csr_matrix(J))
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
            jac.append(sparse.csr_matrix(J))
        return np.concatenate(res), sparse.vstack(jac, format="csr")


def member_rows(
    blocks: list[np.ndarray], idx: np.ndarray, valid: np.ndarray, scale: np.ndarray, M: int
) -> sparse.csr_matrix:
    """Sparse rows (N, 3M·len(blocks)) of per-member Jacobian blocks, each row scaled.

    Parameters
    ----------
    blocks : list of ndarray, shape (N, K, 3)
        Derivatives of each point's residual by the 3 parameters of each of its K member
        metaballs (radii, then centres: the column groups in that order).
    idx : ndarray, shape (N, K), int
        The members (distinct metaballs within a row where ``valid``).
    valid : ndarray, shape (N, K), bool
    scale : ndarray, shape (N,)
        Row weights.
    M : int
        Number of metaballs.

    Returns
    -------
    scipy.sparse.csr_matrix — the sparse form of ``scatter(block) * scale`` side by side.
    """
    N, K = idx.shape
    ok = np.asarray(valid, bool)
    rows = np.broadcast_to(np.arange(N)[:, None, None], (N, K, 3))[ok].ravel()
    data, cols = [], []
    for g, blk in enumerate(blocks):
        data.append((np.asarray(blk) * np.asarray(scale)[:, None, None])[ok].ravel())
        cols.append((3 * M * g + 3 * idx[:, :, None] + np.arange(3))[ok].ravel())
    J = sparse.csr_matrix(
        (np.concatenate(data), (np.tile(rows, len(blocks)), np.concatenate(cols))),
        shape=(N, 3 * M * len(blocks)),
    )
    return J


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
