"""Occluding contours as an observation type of the per-frame weighted least squares.

Issue 7, item 6: the sequence fit (:mod:`core.fit`, :mod:`core.fitting`) can use texture
points, silhouette contours, or both.  A :class:`ContourFrame` holds one frame's image
contours (from the scene's foreground, :func:`scene_contours`) and plugs into
:class:`core.fitting.Observations` (``contours``).  Inside the fit it acts like the
attractor points' re-weighting (IRLS):

* at the start of every re-weighting round (:meth:`ContourFrame.freeze`) the body at the
  current state is rendered into every camera, its visible rim paired with the image
  contours for the parts that selected that camera (visibility ≥ 0.2, observability
  ranking; the public functions of :mod:`core.model_render`, :mod:`core.model_contours`,
  :mod:`core.camera_selection`, :mod:`core.contour_match`, as in
  :func:`core.contour_obs.contour_observations`), and the Huber weights are fixed;
* within the round each pair ``i`` is one observation equation (pixels)

      r_i = n_i · (z_i − proj_c(x_i(θ, root, s, radii, centres))),

  ``z_i`` the image contour point, ``n_i`` its outward image normal, and ``x_i`` the rim
  point held fixed in its metaball's unit-sphere frame
  (``x = c_e + R_e (v_e ∘ l_e ∘ p)``, ``v_e`` its ``visible_scale``),
  so that the residual is a smooth function of every unknown and its analytic Jacobian
  (:func:`contour_block`) is exact;
* each row is divided by the a-priori σ (``ContourSettings.sigma_px``, pixels), which
  weights it against the other observation types by ``p_i / p_j = σ_j² / σ_i²``
  (eq. 12), and multiplied by the square root of its Huber weight (knee ``huber_px``).

The cameras each part used are kept per frame (:attr:`ContourFrame.selection`,
:meth:`ContourFrame.cameras_used`) for the fitted state's quality.

Frames: world Z up, metres; image pixels as in :mod:`core.camera`; angles radians.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera import Camera, camera_project_jacobians
from .camera_selection import Selection, select_cameras
from .contour_match import match_contours
from .contour_obs import containment_observations, contour_mask, silhouette_field
from .contours import Contour, occluding_contours
from .metaballs import Metaballs, world_frames
from .model_contours import rim_points
from .model_render import camera_rays, render_parts
from .skeleton import Skeleton, bone_frames, forward, point_jacobians


@dataclass
class ContourSettings:
    """Contour observations in the fit (units in brackets)."""

    sigma_px: float = 3.0  # a-priori σ of one contour observation [px]
    huber_px: float = 4.0  # knee of the Huber weights [px]
    max_dist_px: float = 12.0  # largest contour ↔ rim pairing distance [px]
    min_visibility: float = 0.2  # a part uses a camera with a visibility index ≥ this
    select: bool = True  # per-part camera selection (False: all cameras fused)
    #: with selection: also rank a part's visible cameras by its predicted contour motion
    #: (the paper's observability); False: every camera with visibility >= min_visibility
    rank_motion: bool = True
    #: body parts that use no contours (names of core.skeleton bones), e.g. the head,
    #: whose template metaballs do not follow a real head's outline (hair, face)
    skip_parts: tuple = ()
    min_matches: int = 40  # a contours-only frame with fewer pairs is diverged
    max_rms_px: float = 6.0  # ... or with a larger RMS of its inlier pairs [px]
    min_part_matches: int = 30  # a part with fewer pairs is hidden to the contours
    #: with points: contours may un-hide a part the points miss.  Off since the tracker
    #: seeds surface across depth jumps (``core track``, :mod:`core.surface_seed`): a
    #: part that two cameras see then has points, and one the points miss is one whose
    #: depth the contours of the line rig cannot fix — un-hidden, it swung away in
    #: depth.  make demo's walk (line3, cues both) with those tracks: un-hiding 27.0 mm
    #: (1 frame diverged, right wrist 148 mm) -> 13.0 mm (none, right wrist 57 mm).
    #: Without the seeding un-hiding was the better choice (the old tracks: 18.1 vs
    #: 25.7 mm; bench.looks' old tracks: 25.7 vs 44.5 mm).
    unhide: bool = False
    #: ... only when its pairs come from at least this many cameras (10 pairs each): one
    #: view's occluding contours leave the part's depth free.  Truth-derived points +
    #: contours on walk_ortho3 (the walker's right limbs seen by no two cameras): 1 ->
    #: MPJPE 75.0 mm, 8 frames diverged; 2 -> 38.3 mm, none (texture alone 27.1 mm).
    #: walk_line3, real tracks: 25.8 -> 25.1 mm, limb segments 43.8 -> 28.2 deg.
    #: Frames with contours alone (no points) un-hide from one view as before.
    unhide_views: int = 2
    #: with contours alone: a part whose pairs come from one camera only keeps its
    #: joints' depth along that camera's rays at the previous frame's, with this σ [m]
    #: (:mod:`core.fit_depth`; None: off).  bench.looks' call, contours alone: skin
    #: look 34.1 -> 27.9 mm, walk_ortho3 26.9 -> 18.9 mm (σ 1.5 cm: 29.6 / 32.5, 6 cm:
    #: 26.6 / 22.6 mm).  Hiding such parts instead
    #: (all their angles held): skin 27.8 mm, walk_ortho3 58.1 mm (both legs lost).
    depth_sigma_m: float | None = 0.03
    #: ... and so does a part whose views' rays to it are at most this many degrees
    #: apart (held along their mean direction): views a few tens of degrees apart see
    #: nearly the same outline (:func:`core.fit_depth.narrow_depth_holds`; 0: one view
    #: only).  line3's outer cameras are 38° apart.  Contours alone, 0 -> 40: sweater
    #: 33.2 -> 26.3 mm, skin 27.9 -> 25.6, jumps_line3 30.0 -> 25.0; pirouette_line3
    #: with selection 176.1 -> 40.3 (fused 39.8 -> 61.2), dance_line3 fused 162.6 ->
    #: 68.2 (selection 205.2 -> 207.7).  The orthogonal rig's views are 90° apart.
    depth_spread_deg: float = 40.0
    textured_scale: float = 1.0  # σ of the pairs of parts that texture points observe, × this
    spacing_px: float = 2.0  # sampling of the image contours [px]
    rim_samples: int = 32  # model rim samples per metaball
    outer_px: float = 3.0  # only rim points with no model pixel this far out (0: all)
    background_frames: int = 20  # frames (evenly spaced) in the background medians
    rounds: int = 3  # re-pairing (re-weighting) rounds per pose solve, at least
    #: σ of the silhouette-containment term [px] (0: off): points inside the metaballs of
    #: the parts the texture points miss must project into every camera's foreground
    #: (:meth:`ContourFrame.containment_block`, :func:`containment_parts`; frames with
    #: points only).  Walk, line3, real tracks, cues both: make demo's tracks MPJPE 29.2
    #: -> 18.1 mm (right wrist 173 -> 63 mm), bench.looks' tracks 25.1 -> 25.7 mm;
    #: walk_ortho3, truth-derived points: 38.3 -> 33.0 mm.  σ 2 px: 24.6 / 24.4 mm; every
    #: part (containment_textured) σ 3 px: 21.0 / 22.3 / 32.8 mm, σ 2 px: 34.5 / 23.7 mm.
    containment_px: float = 3.0
    containment_tol_px: float = 2.0  # ... tolerated distance outside the foreground [px]
    containment_textured: bool = False  # ... also for the parts the texture points observe
    min_fg_frac: float = 0.002  # a foreground mask covering less of the image, ...
    max_fg_frac: float = 0.5  # ... or more, gives no contours for that view
    #: shaping the body from the clicked frame's silhouettes (contours alone, or too few
    #: points there): the metaball centres of these parts leave their template places,
    #: about them with σ ``shape_center_sigma_m`` [m] (None: centres held).  The template
    #: sets trunk, head and feet metaballs on their bones' axes, where a real body's
    #: flesh is not; held there, the silhouettes push the skeleton off in every frame.
    #: The arms keep theirs: too thin for their silhouettes to place them apart from
    #: the pose.
    shape_center_sigma_m: float | None = 0.02
    shape_center_parts: tuple = (
        "pelvis",
        "lowerback",
        "spine",
        "chest",
        "neck",
        "head",
        "l_hip",
        "l_knee",
        "l_ankle",
        "r_hip",
        "r_knee",
        "r_ankle",
    )


@dataclass
class ContourPairs:
    """Frozen contour ↔ rim correspondences of one frame (M pairs).

    Attributes
    ----------
    camera : (M,) int camera index
    ellipsoid : (M,) int metaball of the rim point
    bone : (M,) int its bone (the body part)
    p_unit : (M, 3) the rim point in its metaball's unit-sphere frame
    z : (M, 2) image contour points, pixels
    normal : (M, 2) their outward unit image normals
    """

    camera: np.ndarray
    ellipsoid: np.ndarray
    bone: np.ndarray
    p_unit: np.ndarray
    z: np.ndarray
    normal: np.ndarray

    def __len__(self) -> int:
        return len(self.camera)


def _empty_pairs() -> ContourPairs:
    return ContourPairs(
        np.zeros(0, int),
        np.zeros(0, int),
        np.zeros(0, int),
        np.zeros((0, 3)),
        np.zeros((0, 2)),
        np.zeros((0, 2)),
    )


def match_frame(
    skel: Skeleton,
    balls: Metaballs,
    theta: np.ndarray,
    root: np.ndarray,
    s: np.ndarray,
    cameras: list[Camera],
    contours: list[list[Contour]],
    cfg: ContourSettings,
    theta_rate: np.ndarray | None = None,
    rays: list[np.ndarray] | None = None,
) -> tuple[ContourPairs, Selection]:
    """Pair one frame's image contours with the model's visible rim at a pose.

    Parameters
    ----------
    skel, balls, theta (n,), root (3,), s (G,)
        The body and its pose (radians, metres).
    cameras : list (C) of Camera
    contours : list (C) of list of Contour
    theta_rate : (n,) predicted change of θ per frame, optional; ranks each part's
        cameras by the image motion of its rim (observability); without it every
        camera where the part is visible is used
    rays : list (C) of (H, W, 3) cached viewing rays (:func:`core.model_render.camera_rays`)

    Returns
    -------
    (ContourPairs, Selection) — the pairs and the cameras each part used.
    """
    pose = forward(skel, np.asarray(theta, float)[None], np.asarray(root, float)[None], s)
    Rw, cw = world_frames(skel, pose, balls, s)
    centers, axes, radii = cw[0], Rw[0], balls.visible
    n_parts = len(skel.bone_names)
    renders, rims = [], []
    for c, cam in enumerate(cameras):
        r = render_parts(
            cam, centers, axes, radii, balls.bone, n_parts, rays=None if rays is None else rays[c]
        )
        renders.append(r)
        rim = rim_points(cam, centers, axes, radii, balls.bone, n_per=cfg.rim_samples, render=r)
        if cfg.outer_px > 0:
            rim = rim.select(outer_rim(cam, rim, r.part_id >= 0, cfg.outer_px))
        rims.append(rim)
    vis = np.stack([r.visibility_index for r in renders], axis=1)  # (P, C)
    observ = None
    if cfg.select and cfg.rank_motion and theta_rate is not None:
        observ = np.zeros((n_parts, len(cameras)))
        anc = skel.ancestors()
        for c, (cam, rim) in enumerate(zip(cameras, rims, strict=True)):
            if len(rim) == 0:
                continue
            _, J_th = _rim_point_jacobian(skel, pose, rim.part, rim.xyz, s, anc)
            _, _, J_xyz = camera_project_jacobians(cam, rim.xyz)
            duv = np.einsum("mij,mjk,k->mi", J_xyz, J_th, np.asarray(theta_rate, float))
            sums = np.zeros((n_parts, 2))
            np.add.at(sums, rim.part, duv)
            observ[:, c] = np.linalg.norm(sums, axis=1)
    if cfg.select:
        sel = select_cameras(vis, observ, min_visibility=cfg.min_visibility)
    else:
        sel = select_cameras(np.where(np.isfinite(vis), 1.0, np.nan))
    sel.use[:, [not contours[c] for c in range(len(cameras))]] = False  # nothing to pair
    if cfg.skip_parts:
        sel.use[[skel.bone_index(b) for b in cfg.skip_parts]] = False
    out = []
    for c, (cam, rim) in enumerate(zip(cameras, rims, strict=True)):
        use_parts = np.flatnonzero(sel.use[:, c])
        if len(use_parts) == 0 or len(rim) == 0 or not contours[c]:
            continue
        m = match_contours(cam, contours[c], rim, max_dist_px=cfg.max_dist_px, parts=use_parts)
        if len(m) == 0:
            continue
        e = rim.ellipsoid[m.rim_index]
        x = rim.xyz[m.rim_index]
        p_unit = np.einsum("mji,mj->mi", axes[e], x - centers[e]) / radii[e]
        out.append(
            ContourPairs(
                np.full(len(m), c), e, balls.bone[e], p_unit, m.contour_uv, m.contour_normal
            )
        )
    if not out:
        return _empty_pairs(), sel
    return ContourPairs(
        *(
            np.concatenate([getattr(p, k) for p in out])
            for k in ("camera", "ellipsoid", "bone", "p_unit", "z", "normal")
        )
    ), sel


def outer_rim(camera: Camera, rim, mask: np.ndarray, offset_px: float = 3.0) -> np.ndarray:
    """Which rim points lie on the outline of the model's whole silhouette, shape (M,) bool.

    An image contour is the outline of the person's foreground, so only model rim points
    with background just outside them can correspond to it: a limb's rim in front of the
    trunk (an internal occluding contour) is inside the silhouette and has no image
    contour to pair with.  The test samples ``mask`` (H, W) (the model's rendering) at
    ``offset_px`` along the projected outward surface normal.
    """
    if len(rim) == 0:
        return np.zeros(0, bool)
    step = 0.01  # metres along the 3-D normal, to get its image direction
    d = camera.project(rim.xyz + step * rim.normal) - rim.uv
    nd = np.linalg.norm(d, axis=1, keepdims=True)
    d = np.where(nd > 1e-9, d / np.maximum(nd, 1e-9), 0.0)
    p = np.round(rim.uv + offset_px * d).astype(int)
    h, w = mask.shape
    inside = (p[:, 0] >= 0) & (p[:, 0] < w) & (p[:, 1] >= 0) & (p[:, 1] < h)
    covered = np.zeros(len(p), bool)
    covered[inside] = mask[p[inside, 1], p[inside, 0]]
    return ~covered


def _rim_point_jacobian(skel, pose, bone, xyz, s, anc):
    """World positions (M, 3) and d x / d θ (M, 3, n) of points fixed in their bones."""
    Rb, pb = bone_frames(skel, pose)
    q0 = np.einsum("mji,mj->mi", Rb[0, bone], xyz - pb[0, bone])
    x, J_theta, _ = point_jacobians(skel, pose, bone, q0, np.full(len(bone), -1), s, anc)
    return x[0], J_theta[0]


def contour_block(
    skel: Skeleton,
    balls: Metaballs,
    theta: np.ndarray,
    root: np.ndarray,
    s: np.ndarray,
    cameras: list[Camera],
    pairs: ContourPairs,
    anc: np.ndarray | None = None,
    shape: bool = True,
):
    """Residuals and analytic Jacobians of frozen contour pairs at a state.

    Parameters
    ----------
    skel, balls : the body (``balls.radii`` (M, 3) and ``balls.center0`` (M, 3) are the
        current shape unknowns)
    theta : (n,) radians; root : (3,) metres; s : (G,) bone scales
    cameras : list (C) of Camera
    pairs : ContourPairs (K pairs)
    shape : also return the Jacobians w.r.t. s, the radii and the centres

    Returns
    -------
    r : (K,) ``n · (z − proj(x))``, pixels (unweighted)
    J_theta : (K, n) px/rad; J_root : (K, 3) px/m; J_s : (K, G) px;
    J_radii : (K, 3M) px/m; J_centers : (K, 3M) px/m (the last three None when not shape)
    """
    n, G, M = skel.n_dof, skel.n_groups, len(balls.radii)
    K = len(pairs)
    r = np.zeros(K)
    J_t, J_r = np.zeros((K, n)), np.zeros((K, 3))
    J_s = np.zeros((K, G)) if shape else None
    J_rad = np.zeros((K, 3 * M)) if shape else None
    J_c = np.zeros((K, 3 * M)) if shape else None
    if K == 0:
        return r, J_t, J_r, J_s, J_rad, J_c
    anc = skel.ancestors() if anc is None else anc
    pose = forward(skel, np.asarray(theta, float)[None], np.asarray(root, float)[None], s)
    Rw, cw = world_frames(skel, pose, balls, s)
    Rb, _ = bone_frames(skel, pose)
    e, bone = pairs.ellipsoid, pairs.bone
    local = balls.visible[e] * pairs.p_unit  # (K, 3) in the metaball's axes
    xyz = cw[0, e] + (Rw[0, e] @ local[:, :, None])[:, :, 0]
    _, J_th = _rim_point_jacobian(skel, pose, bone, xyz, s, anc)
    nJ = np.zeros((K, 3))  # n^T d proj / d x
    for c, cam in enumerate(cameras):
        k = np.flatnonzero(pairs.camera == c)
        if not len(k):
            continue
        uv, _, J_xyz = camera_project_jacobians(cam, xyz[k])
        r[k] = np.sum(pairs.normal[k] * (pairs.z[k] - uv), axis=1)
        nJ[k] = (pairs.normal[k][:, None, :] @ J_xyz)[:, 0]
    J_t[:] = -(nJ[:, None, :] @ J_th)[:, 0]
    J_r[:] = -nJ
    if shape:
        # bone scales: the DOF offsets above the point (point_jacobians' J_s of a point
        # with no group) and the metaball's own centre c0 · s_g in its bone's frame
        q0 = np.zeros((K, 3))
        _, _, Js0 = point_jacobians(skel, pose, bone, q0, np.full(K, -1), s, anc)
        g = balls.group[e]
        own = np.einsum("kij,kj->ki", Rb[0, bone], balls.center0[e])
        Js = Js0[0].copy()
        has = np.flatnonzero(g >= 0)
        Js[has, :, g[has]] += own[has]
        J_s[:] = -np.einsum("kj,kjg->kg", nJ, Js)
        cols = 3 * e[:, None] + np.arange(3)[None]
        # radii: d x / d l_e = R_e diag(visible_scale p)
        d_rad = -np.einsum("kj,kji->ki", nJ, Rw[0, e]) * balls.vscale[e] * pairs.p_unit
        np.put_along_axis(J_rad, cols, d_rad, axis=1)
        scale = np.where(g >= 0, np.asarray(s, float)[np.maximum(g, 0)], 1.0)
        d_cen = -np.einsum("kj,kji->ki", nJ, Rb[0, bone]) * scale[:, None]
        np.put_along_axis(J_c, cols, d_cen, axis=1)
    return r, J_t, J_r, J_s, J_rad, J_c


def containment_parts(
    counts: np.ndarray, with_points: bool, min_part_points: int, cfg: ContourSettings
) -> np.ndarray:
    """The parts the silhouette containment holds in one frame, shape (P,) bool.

    ``counts`` (P,) are the texture points near each part.  In a frame with points the
    term holds the parts with fewer than ``min_part_points`` of them — a limb the points
    miss, which one view's contours cannot place in depth and which otherwise follows
    its prediction — or every part with ``cfg.containment_textured``.  In a frame with
    contours alone it holds none: there the silhouette limb search places the limbs
    (skin walk, line3, σ 3 px on every part: MPJPE 29.0 -> 37.4 mm).
    """
    counts = np.asarray(counts)
    if not with_points:
        return np.zeros(len(counts), bool)
    return (counts < min_part_points) | bool(cfg.containment_textured)


def _huber_sqrt(r: np.ndarray, k: float) -> np.ndarray:
    a = np.abs(r)
    return np.where(a <= k, 1.0, np.sqrt(k / np.maximum(a, 1e-300)))


class ContourFrame:
    """One frame's contour observations for :class:`core.fitting.Observations`.

    Parameters
    ----------
    cameras : list (C) of Camera
    contours : list (C) of list of Contour — the frame's image occluding contours
    settings : ContourSettings
    rays : list (C) of (H, W, 3) cached viewing rays, optional (shared between frames)
    theta_rate : (n,) predicted change of θ per frame, optional (observability ranking)

    Attributes
    ----------
    pairs : ContourPairs or None — the correspondences of the last :meth:`freeze`
    weights : (K,) row weights ``sqrt(huber) / σ`` of those pairs
    selection : Selection or None — the cameras each part used at the last freeze
    part_scale : (P,) factor on σ per body part, or None (1) — set by the sequence fit to
        ``textured_scale`` for the parts its texture points observe, so that the contours
        (whose metaball outline is not the body's) mainly place the parts the points miss
    containment_parts : (P,) bool of the parts the silhouette containment holds, or None
        (every part) — set by the sequence fit (:attr:`ContourSettings.containment_px`)
    """

    def __init__(
        self,
        cameras: list[Camera],
        contours: list[list[Contour]],
        settings: ContourSettings | None = None,
        rays: list[np.ndarray] | None = None,
        theta_rate: np.ndarray | None = None,
    ):
        if len(contours) != len(cameras):
            raise ValueError(f"{len(contours)} contour lists for {len(cameras)} cameras")
        self.cameras = list(cameras)
        self.contours = contours
        self.cfg = settings or ContourSettings()
        self.rays = rays
        self.theta_rate = theta_rate
        self.pairs: ContourPairs | None = None
        self.weights = np.zeros(0)
        self.selection: Selection | None = None
        self.part_scale: np.ndarray | None = None
        self.containment_parts: np.ndarray | None = None
        self._key: bytes | None = None
        self._masks: list | None = None
        self._grids: list | None = None
        self._fields: list | None = None

    @property
    def n_contour_points(self) -> int:
        return int(sum(len(c) for cam in self.contours for c in cam))

    def freeze(
        self, skel: Skeleton, balls: Metaballs, theta: np.ndarray, root: np.ndarray, s: np.ndarray
    ) -> None:
        """Pair the contours with the rim at this state and fix the Huber weights."""
        scale = np.zeros(0) if self.part_scale is None else self.part_scale
        key = b"".join(
            np.ascontiguousarray(a, float).tobytes()
            for a in (theta, root, s, balls.radii, balls.center0, scale)
        )
        if key == self._key and self.pairs is not None:
            return
        if self.n_contour_points == 0:
            self.pairs, self.selection = _empty_pairs(), None
        else:
            self.pairs, self.selection = match_frame(
                skel,
                balls,
                theta,
                root,
                s,
                self.cameras,
                self.contours,
                self.cfg,
                theta_rate=self.theta_rate,
                rays=self.rays,
            )
        r = contour_block(skel, balls, theta, root, s, self.cameras, self.pairs, shape=False)[0]
        sig = np.full(len(r), self.cfg.sigma_px)
        if self.part_scale is not None and len(r):
            sig = sig * np.asarray(self.part_scale, float)[self.pairs.bone]
        self.weights = _huber_sqrt(r / (sig / self.cfg.sigma_px), self.cfg.huber_px) / sig
        self._key = key

    def block(
        self,
        skel: Skeleton,
        balls: Metaballs,
        theta: np.ndarray,
        root: np.ndarray,
        s: np.ndarray,
        anc: np.ndarray | None = None,
        shape: bool = True,
    ):
        """Weighted residual rows ``(r, J_theta, J_root, J_s, J_radii, J_centers)`` of
        the frozen pairs (see :func:`contour_block`; every row times ``weights``)."""
        if self.pairs is None:
            self.freeze(skel, balls, theta, root, s)
        out = contour_block(skel, balls, theta, root, s, self.cameras, self.pairs, anc, shape)
        w = self.weights
        return tuple(None if a is None else (a * w if a.ndim == 1 else a * w[:, None]) for a in out)

    def containment_block(
        self, skel: Skeleton, balls: Metaballs, theta: np.ndarray, root: np.ndarray, s: np.ndarray
    ):
        """Silhouette-containment rows ``(r, J_theta, J_root)`` at a state, or None when
        the term is off (``containment_px`` 0), holds no part (:attr:`containment_parts`)
        or no camera has contours.

        :func:`core.contour_obs.containment_observations` (seven points inside every
        metaball, each a residual ``max(D − tol, 0)`` of the distance ``D`` outside the
        foreground, pixels), re-evaluated at every state — unlike the contour pairs it
        needs no correspondence, so its reach is the whole image — divided by
        ``containment_px`` and robust: above the Huber knee ``huber_px`` a residual
        ``r`` becomes ``sqrt(2 k r − k²)`` (its square is the Huber loss).
        """
        k_px = self.cfg.containment_px
        held = self.containment_parts
        if k_px <= 0 or (held is not None and not np.any(held)):
            return None
        if self._fields is None:
            self._fields = [
                silhouette_field(cons, cam.size) if cons else None
                for cons, cam in zip(self.contours, self.cameras, strict=True)
            ]
        use = [c for c, f in enumerate(self._fields) if f is not None]
        if not use:
            return None
        co = containment_observations(
            skel,
            np.asarray(theta, float),
            np.asarray(root, float),
            s,
            balls,
            [self.cameras[c] for c in use],
            [self._fields[c] for c in use],
            tol_px=self.cfg.containment_tol_px,
            keep_parts=held,
        )
        k = self.cfg.huber_px
        r = co.residual
        big = r > k
        r_eff = np.where(big, np.sqrt(np.maximum(2.0 * k * r - k * k, 0.0)), r)
        d = np.where(big, k / np.maximum(r_eff, 1e-12), 1.0) / k_px
        return r_eff / k_px, co.J_theta * d[:, None], co.J_root * d[:, None]

    def masks(self) -> list:
        """Foreground (H, W) bool of every camera, enclosed by its contours (None for a
        camera without contours); computed once."""
        if self._masks is None:
            self._masks = [
                contour_mask(cons, cam.size) if cons else None
                for cons, cam in zip(self.contours, self.cameras, strict=True)
            ]
        return self._masks

    def grids(self) -> list:
        """:func:`core.silhouette_search.mask_grid` of every camera's :meth:`masks`."""
        from .silhouette_search import MaskGrid, mask_grid

        if self._grids is None:
            self._grids = [
                mask_grid(m) if m is not None else MaskGrid(np.zeros((0, 2)), np.zeros(0, bool), 2)
                for m in self.masks()
            ]
        return self._grids

    def part_counts(self, n_parts: int, min_views: int = 1) -> np.ndarray:
        """Pairs per body part at the last freeze, shape (P,); 0 for a part whose pairs
        come from fewer than ``min_views`` cameras with 10 or more pairs each."""
        if self.pairs is None or not len(self.pairs):
            return np.zeros(n_parts, int)
        counts = np.bincount(self.pairs.bone, minlength=n_parts)[:n_parts]
        if min_views > 1:
            C = len(self.cameras)
            per = np.bincount(self.pairs.bone * C + self.pairs.camera, minlength=n_parts * C)[
                : n_parts * C
            ].reshape(n_parts, C)
            counts = np.where((per >= 10).sum(axis=1) >= min_views, counts, 0)
        return counts

    def stats(
        self, skel: Skeleton, balls: Metaballs, theta: np.ndarray, root: np.ndarray, s: np.ndarray
    ) -> dict:
        """Re-pair at a (final) state: ``{"n": pairs, "rms_px": RMS of the pairs within
        3 knees, "inl": their share, "cost": Σ min(|r|, 3 knees)²}`` (pixels)."""
        self.freeze(skel, balls, theta, root, s)
        r = contour_block(skel, balls, theta, root, s, self.cameras, self.pairs, shape=False)[0]
        tau = 3.0 * self.cfg.huber_px
        inl = np.abs(r) <= tau
        return {
            "n": len(r),
            "inl": float(inl.mean()) if len(r) else 0.0,
            "rms_px": float(np.sqrt(np.mean(r[inl] ** 2))) if inl.any() else np.inf,
            "cost": float(np.sum(np.minimum(np.abs(r), tau) ** 2)),
        }

    def cameras_used(self, skel: Skeleton) -> dict:
        """``{part name: [camera names]}`` of the last freeze (empty before one)."""
        if self.selection is None:
            return {}
        use = self.selection.use
        return {
            skel.bone_names[p]: [self.cameras[c].name for c in np.flatnonzero(use[p])]
            for p in range(min(len(skel.bone_names), len(use)))
        }


# -- image contours of a scene ------------------------------------------------------------
@dataclass
class SceneContours:
    """Image occluding contours of a scene.

    Attributes
    ----------
    contours : list (F) of list (C) of list of Contour
    view_ok : (F, C) bool — the foreground of that view was plausible (covering between
        ``min_fg_frac`` and ``max_fg_frac`` of the image); contours of other views are empty
    camera_ok : (C,) bool — the camera's background model is usable (plausible
        foreground in at least half of the frames)
    messages : list of str
    """

    contours: list
    view_ok: np.ndarray
    camera_ok: np.ndarray
    messages: list


def contours_from_frames(
    frames: np.ndarray, cfg: ContourSettings | None = None
) -> tuple[list[list[Contour]], np.ndarray]:
    """Foreground contours of one camera's take (robust temporal median background).

    Parameters
    ----------
    frames : (N, H, W, 3) or (N, H, W) uint8

    Returns
    -------
    contours : list (N) of list of Contour (empty where the mask is implausible)
    ok : (N,) bool — plausible foreground (see :class:`SceneContours`)
    """
    from .background import fit_background

    cfg = cfg or ContourSettings()
    model = fit_background(frames, max_frames=cfg.background_frames)
    out, ok = [], np.zeros(len(frames), bool)
    for i, img in enumerate(frames):
        mask = model.foreground(img)
        frac = float(mask.mean())
        ok[i] = cfg.min_fg_frac <= frac <= cfg.max_fg_frac
        out.append(occluding_contours(mask, spacing=cfg.spacing_px) if ok[i] else [])
        ok[i] &= len(out[-1]) > 0
    return out, ok


def scene_contours(
    scene, cameras: list[Camera], n_frames: int, cfg: ContourSettings | None = None, progress=None
) -> SceneContours:
    """Image contours of the first ``n_frames`` frames of every camera of a scene
    (:func:`contours_from_frames` per camera, from the whole take's background)."""
    cfg = cfg or ContourSettings()
    C = len(scene.cameras)
    per_cam, oks, msgs = [], [], []
    for c, name in enumerate(scene.cameras):
        frames = np.array([scene.image(name, i, color=True) for i in range(scene.n_frames)])
        cons, ok = contours_from_frames(frames, cfg)
        per_cam.append(cons[:n_frames])
        oks.append(ok[:n_frames])
        if progress is not None:
            progress.update(c + 1, C, f"foreground contours: camera {name}")
    view_ok = np.stack(oks, axis=1) if oks else np.zeros((n_frames, 0), bool)
    camera_ok = view_ok.mean(axis=0) >= 0.5 if n_frames else np.zeros(C, bool)
    for c in np.flatnonzero(~camera_ok):
        msgs.append(
            f"camera {scene.cameras[c]}: no usable background/foreground "
            f"(plausible person mask in {int(view_ok[:, c].sum())} of {n_frames} "
            "frames): its contours are not used"
        )
        for f in range(n_frames):
            per_cam[c][f] = []
    view_ok &= camera_ok[None]
    contours = [[per_cam[c][f] for c in range(C)] for f in range(n_frames)]
    return SceneContours(contours, view_ok, camera_ok, msgs)


def contour_frames(
    cameras: list[Camera], contours: list[list[list[Contour]]], cfg: ContourSettings | None = None
) -> list[ContourFrame]:
    """One :class:`ContourFrame` per frame, sharing the cameras' cached rays."""
    rays = [camera_rays(c) for c in cameras]
    return [ContourFrame(cameras, fc, cfg, rays=rays) for fc in contours]
