"""Single-camera texture flow on the fitted body (beyond paper 1: model-based image motion).

Least squares matching between cameras needs a surface patch that looks alike in two
views: the orthogonal rig (no patch looks alike in two of its cameras) gets no 3-D point
at all, and its motion comes from the contours alone.  Each camera still sees the
texture on the body move.  After a frame is fitted, good corners
(``cv2.goodFeaturesToTrack``) on every part's visible, foreground region of each camera
are *lifted* onto the fitted body: the z-buffer of the rendered ellipsoids
(:func:`core.model_render.render_parts`) gives the surface point under the pixel, which
is stored in its bone's frame (``q0``).  The corners are followed into the next frame's
image of the same camera by pyramidal Lucas–Kanade with a forward–backward check (with
``refine_lsm``, then by least squares matching from the previous image: Lucas–Kanade
trails a turning surface, :mod:`bench.flow_truth`); each followed corner ``z`` (pixels)
is an observation of that bone-fixed point's projection (two equations, pixels)

    r_i = π_c(p_b(θ, root, s) + R_b(θ) q0_i) − z_i,

divided by its σ (``sigma_px``) and weighted by a Cauchy weight of its residual norm in
σ units, frozen per re-weighting round.  ``q0`` is held, so the analytic Jacobian
(:func:`core.skeleton.point_jacobians` through :func:`core.camera.camera_project_jacobians`)
is exact.

A corner keeps the point it was first lifted at for as long as it is followed and
stays on its part within ``keep_px`` of that point's projection (``persist``): lifted
afresh every frame, each frame's observations would only repeat the last fitted pose's
error plus the image motion, and the errors would add up (walk_ortho3: 30.4 mm frame to
frame at σ 1 px, 21.7 mm persistent).  The metaball surface is not the body's: the
lifted depth carries that error, which moves the projection little for the rotations a
corner lives through.  By default the flow is used only in frames without enough 3-D
points (``without_points_only``).

Corners lost and lifted again carry the pose error of the frame they are lifted at,
so on a rig without 3-D points an error, once made, stays.  The *texture reference*
(``reference``, :mod:`core.fit_reference`) holds the clicked frame's texture: its
corners, lifted onto the clicked pose (:meth:`FlowAnchors.set_reference`), are matched
by least squares from the clicked frame's image into every later frame, as
observations of the same form as a followed corner's.

Frames: world Z up, metres; image pixels with integer coordinates at pixel centres.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .camera import Camera, camera_project_jacobians
from .fit_reference import TextureReference, surface_tangents
from .fit_trajectory import cauchy_row_weights
from .metaballs import Metaballs, world_frames
from .model_render import camera_rays, render_parts
from .skeleton import Skeleton, bone_frames, forward, point_jacobians


@dataclass
class FlowSettings:
    """Corner selection, image tracking and weights of the flow observations."""

    per_part: int = 30  # corners per part and camera at most
    min_distance_px: float = 4.0  # between corners
    quality: float = 0.02  # goodFeaturesToTrack's quality level
    erode_px: int = 3  # corners this far inside the part's visible region and foreground
    min_visibility: float = 0.2  # parts less visible in a camera give it no corners
    window_px: int = 15  # Lucas–Kanade window
    levels: int = 2  # pyramid levels above the image
    fb_px: float = 0.5  # largest forward–backward disagreement, pixels
    #: each followed corner refined by least squares matching (affine + radiometric,
    #: :func:`core.lsm.match`) from the previous frame's image, started where
    #: Lucas–Kanade put it.  Lucas–Kanade's one shift per 15 px window falls short of
    #: a turning surface's motion: on dance_ortho3's true mesh, head corners trail
    #: their material points by 0.07–0.71 px on average per 5–9 px frame-to-frame move
    #: (90th percentile error 0.7–1.1 px); refined, 0.05–0.13 px (0.25–0.6).  Off: the
    #: pirouette gains in each of four draws (median 23.35 -> 22.55 mm), but the dance
    #: loses limbs (26.25 -> 36.3); with ``refine_drop`` False the dance keeps them
    #: (26.25) and the pirouette loses (24.6; docs/design.md, "Lucas–Kanade trails a
    #: turning surface").  ``SequenceSettings.flow_choice`` fits a take the silhouettes
    #: shaped both ways and keeps the fit the foregrounds explain better
    refine_lsm: bool = False
    refine_max_shift_px: float = 3.0  # LSM's largest move from Lucas–Kanade's point
    refine_max_sigma_px: float = 0.3  # LSM's largest σ of a refined corner, pixels
    refine_drop: bool = True  # a corner LSM rejects is dropped; False: Lucas–Kanade's kept
    #: a-priori σ of a followed corner, pixels.  3 -> 1.5 (in-process on the scenes'
    #: tracks, cues both, one run each): walk_ortho3 17.6 -> 15.7 mm (neck 9.9 -> 6.5,
    #: left shoulder 20.7 -> 11.1, right knee 30.2 -> 19.5), the skin walk 16.9 -> 16.2;
    #: 1.0: 15.6 / 16.2 (walk_ortho3's right ankle 11 -> 33 mm); 6.0: 17.5 on walk_ortho3
    sigma_px: float = 1.5
    robust_scale: float = 3.0  # Cauchy knee, σ units
    #: corners keep the surface point of the frame they were lifted at, for as long as
    #: they are followed and stay within ``keep_px`` of its projection on their visible
    #: part (new ones fill the parts that have fewer than ``per_part``); False: every
    #: frame lifts afresh (frame-to-frame, whose errors add up)
    persist: bool = True
    keep_px: float = 3.0
    #: use the flow only in frames with fewer 3-D points than the sequence fit's
    #: ``min_points`` (the orthogonal rig, bare skin): beside the points of a body that
    #: hides a limb in every camera, the corners on the hidden limb's rendered region
    #: lie on whatever the image shows there and move the limb with it (make demo's
    #: walk 10.93 -> 13.63 mm when used in every frame)
    without_points_only: bool = True
    #: a texture reference from the clicked frame: its corners, lifted onto the clicked
    #: (most trusted) pose, are matched by least squares straight from the clicked
    #: frame's image into each later frame's, so their surface points carry no error the
    #: fit made since (docs/design.md, "A texture reference from the clicked frame";
    #: bench.fit_spread, off -> on, MPJPE mm): walk_ortho3 runs 0-3 11.77 / 13.32 /
    #: 13.10 / 13.06 -> 10.3 / 11.0 / 11.2 / 12.3; dance_ortho3 median of 4 27.1 -> 27.7
    reference: bool = True
    reference_sigma_px: float = 1.5
    reference_depth_m: float = 0.03  # a point deeper than the rendered surface is hidden
    reference_search_px: float = 3.0  # LSM's largest move from its start, pixels
    reference_max_sigma_px: float = 0.3  # LSM's largest σ of a matched point, pixels
    #: a reference corner whose match lies farther than this from its projection on
    #: the frame's accepted fit is dropped for good (a false lock, or hidden behind a
    #: part the model misplaces), pixels; None: kept
    reference_drop_px: float | None = 4.0
    #: the parts (bone names) the reference is kept on; None: all
    reference_parts: tuple | None = None
    #: match each reference corner in the other cameras too, wherever the fitted body
    #: shows it from a like direction there (a turned body shows one camera what
    #: another saw at the clicked frame): the model's affine from the clicked image to
    #: the camera, its singular values within a factor ``reference_across_stretch``
    #: of each other and of 1, and the point seen within ``reference_across_deg`` of
    #: its clicked ray (its depth error, from the metaball surface, shows across that
    #: angle's sine).  Off: the matches are right (dance_ortho3 run 0: 845, median
    #: 0.36 px from the truth's points), but the fit does not gain (walk_ortho3 runs
    #: 0 / 1 10.3 / 11.0 -> 10.50 / 10.71 mm; the dance trades one lost limb for
    #: another; docs/design.md, "Reference corners matched in the other cameras")
    reference_across: bool = False
    reference_across_stretch: float = 1.5
    reference_across_deg: float = 30.0
    #: each reference corner's depth along its clicked ray, refined from its matches
    #: over the frames (a 1-D least squares at each accepted fit; a match farther than
    #: ``reference_depth_gate_px`` from its projection does not count): lifted onto
    #: the metaball surface, the point is off the true surface by up to a centimetre
    #: along that ray, which a camera 30-50° off it sees.  Off: the refined depths take
    #: up the accepted poses' errors (with across, run 0: walk_ortho3 10.68 -> 11.03 mm,
    #: dance_ortho3 25.05 -> 34.77)
    reference_depth: bool = False
    reference_depth_prior_m: float = 0.04  # σ of its prior towards 0, a match σ 1 px
    reference_depth_max_m: float = 0.04  # the largest refinement, metres
    reference_depth_gate_px: float = 3.0


@dataclass
class FlowObs:
    """One frame's flow observations (K corners).

    Attributes
    ----------
    bone : (K,) int — the part (bone index) each corner was lifted onto
    q0 : (K, 3) its surface point in the bone's frame at the previous frame, metres
    camera : (K,) int — the camera that followed it
    uv : (K, 2) where it was followed to in this frame, pixels
    sigma : (K,) a-priori σ per image coordinate, pixels
    """

    cameras: list
    bone: np.ndarray
    q0: np.ndarray
    camera: np.ndarray
    uv: np.ndarray
    sigma: np.ndarray
    robust_scale: float = 3.0
    weights: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.bone)

    def residuals(self, skel: Skeleton, theta, root, s, anc=None, jacobians: bool = True):
        """Unweighted ``π(x) − z`` (K, 2) pixels and, with ``jacobians``, its derivatives
        w.r.t. θ (K, 2, n), the root (K, 2, 3) and the bone scales (K, 2, G)."""
        pose = forward(skel, np.asarray(theta, float)[None], np.asarray(root, float)[None], s)
        K = len(self.bone)
        if jacobians:
            x, Jt, Js = point_jacobians(skel, pose, self.bone, self.q0, np.full(K, -1), s, anc)
            x, Jt, Js = x[0], Jt[0], Js[0]
        else:
            Rb, pb = bone_frames(skel, pose)
            x = pb[0, self.bone] + np.einsum("nij,nj->ni", Rb[0, self.bone], self.q0)
        r = np.zeros((K, 2))
        Jx = np.zeros((K, 2, 3))
        for c in np.unique(self.camera):
            k = self.camera == c
            uv, _, J = camera_project_jacobians(self.cameras[c], x[k])
            r[k] = uv - self.uv[k]
            Jx[k] = J
        if not jacobians:
            return r, None, None, None
        return r, Jx @ Jt, Jx, Jx @ Js

    def freeze(self, skel: Skeleton, theta, root, s) -> None:
        """Fix the row weights at this state (IRLS)."""
        r = self.residuals(skel, theta, root, s, jacobians=False)[0]
        w = cauchy_row_weights(r, self.sigma, self.robust_scale)
        self.weights = np.where(np.isfinite(w), w, 0.0)

    def block(self, skel: Skeleton, theta, root, s, anc=None, n_shape: int | None = None):
        """Weighted rows ``(r (2K,), J_theta (2K, n), J_root (2K, 3), J_s (2K, G),
        J_radii, J_centers)``; the last two zero (2K, n_shape) or None without
        ``n_shape`` (pose-only solves)."""
        if self.weights is None:
            self.freeze(skel, theta, root, s)
        r, Jt, Jr, Js = self.residuals(skel, theta, root, s, anc)
        w = np.repeat(self.weights, 2)
        K = len(self.bone)
        zero = None if n_shape is None else np.zeros((2 * K, n_shape))
        r = np.where(np.isfinite(r), r, 0.0)
        return (
            r.reshape(-1) * w,
            Jt.reshape(2 * K, -1) * w[:, None],
            Jr.reshape(2 * K, 3) * w[:, None],
            Js.reshape(2 * K, -1) * w[:, None],
            zero,
            None if zero is None else zero.copy(),
        )


def lift_corners(
    skel: Skeleton,
    balls: Metaballs,
    theta,
    root,
    s,
    camera: Camera,
    image: np.ndarray,
    foreground: np.ndarray | None,
    cfg: FlowSettings,
    rays: np.ndarray | None = None,
    keep=None,
    ren=None,
):
    """Corners of one camera's image on the fitted body, lifted onto its surface.

    Parameters
    ----------
    skel, balls, theta (n,), root (3,), s (G,) : the fitted body and pose
    camera : Camera
    image : (H, W) uint8 grey image of the fitted frame
    foreground : (h, w) bool, or None — corners only inside it (eroded; resized to the
        camera's image when the masks have another resolution)
    rays : (H, W, 3) the camera's unit viewing rays (:func:`core.model_render.camera_rays`)
    keep : (uv (M, 2), bone (M,), q0 (M, 3)) or None — corners followed into this frame
        that keep their surface points: those still on their part's visible region and
        within ``cfg.keep_px`` of their point's projection stay, and new corners only
        fill their parts up to ``cfg.per_part``, ``cfg.min_distance_px`` from them
    ren : PartRender of this pose in this camera, or None (rendered here)

    Returns
    -------
    (uv (K, 2) pixels, bone (K,) int, q0 (K, 3) metres in the bone's frame) — the kept
    corners first
    """
    pose = forward(skel, np.asarray(theta, float)[None], np.asarray(root, float)[None], s)
    n_parts = len(skel.bone_names)
    if ren is None:
        ren = render_body(skel, balls, pose, s, camera, rays)
    vis = ren.visibility_index
    kernel = np.ones((2 * cfg.erode_px + 1,) * 2, np.uint8)
    fg = None
    if foreground is not None:
        fg = foreground.astype(np.uint8)
        if fg.shape != ren.part_id.shape:  # masks at another resolution than the images
            fg = cv2.resize(fg, camera.size, interpolation=cv2.INTER_NEAREST)
        fg = cv2.erode(fg, kernel)
    Rb, pb = bone_frames(skel, pose)
    k_uv, k_bone, k_q0 = np.zeros((0, 2)), np.zeros(0, int), np.zeros((0, 3))
    if keep is not None and len(keep[0]):
        k_uv, k_bone, k_q0 = keep
        x = pb[0, k_bone] + np.einsum("nij,nj->ni", Rb[0, k_bone], k_q0)
        iu = np.clip(np.rint(k_uv[:, 0]).astype(int), 0, camera.size[0] - 1)
        iv = np.clip(np.rint(k_uv[:, 1]).astype(int), 0, camera.size[1] - 1)
        ok = (np.linalg.norm(camera.project(x) - k_uv, axis=1) <= cfg.keep_px) & (
            ren.part_id[iv, iu] == k_bone
        )
        if fg is not None:
            ok &= fg[iv, iu] > 0
        k_uv, k_bone, k_q0 = k_uv[ok], k_bone[ok], k_q0[ok]
    taken = np.full(ren.part_id.shape, 255, np.uint8)  # 0 near the kept corners
    for u, v in np.rint(k_uv).astype(int):
        cv2.circle(taken, (int(u), int(v)), int(np.ceil(cfg.min_distance_px)), 0, -1)
    have = np.bincount(k_bone, minlength=n_parts)
    uvs, bones = [], []
    for b in np.flatnonzero(ren.visible_area > 0):
        want = cfg.per_part - have[b]
        if not vis[b] >= cfg.min_visibility or want <= 0:
            continue
        m = cv2.erode((ren.part_id == b).astype(np.uint8), kernel) & (taken > 0)
        if fg is not None:
            m &= fg
        if m.sum() < 9:
            continue
        pts = cv2.goodFeaturesToTrack(image, int(want), cfg.quality, cfg.min_distance_px, mask=m)
        if pts is None:
            continue
        uvs.append(pts.reshape(-1, 2).astype(float))
        bones.append(np.full(len(uvs[-1]), b))
    if not uvs:
        return k_uv, k_bone, k_q0
    uv = np.concatenate(uvs)
    bone = np.concatenate(bones)
    iu = np.clip(np.rint(uv[:, 0]).astype(int), 0, camera.size[0] - 1)
    iv = np.clip(np.rint(uv[:, 1]).astype(int), 0, camera.size[1] - 1)
    depth = ren.depth[iv, iu]
    ok = np.isfinite(depth) & (ren.part_id[iv, iu] == bone)
    # the surface point under the corner's own (sub-pixel) ray
    _, d = camera.rays(uv[ok])
    xyz = camera.center + depth[ok, None] * d
    b = bone[ok]
    q0 = np.einsum("nji,nj->ni", Rb[0, b], xyz - pb[0, b])
    return (np.concatenate([k_uv, uv[ok]]), np.concatenate([k_bone, b]), np.concatenate([k_q0, q0]))


def render_body(skel: Skeleton, balls: Metaballs, pose, s, camera: Camera, rays=None):
    """The part render (:class:`core.model_render.PartRender`) of the body in ``pose``
    (:func:`core.skeleton.forward` of one frame) seen by ``camera``."""
    Rw, cw = world_frames(skel, pose, balls, s)
    rays = camera_rays(camera) if rays is None else rays
    n_parts = len(skel.bone_names)
    return render_parts(camera, cw[0], Rw[0], balls.visible, balls.bone, n_parts, rays=rays)


def follow_corners(
    img0: np.ndarray, img1: np.ndarray, uv: np.ndarray, cfg: FlowSettings, guess=None
):
    """Pyramidal Lucas–Kanade from ``img0`` to ``img1`` (uint8 (H, W)) of corners
    ``uv`` (K, 2) pixels, started at ``guess`` (K, 2) pixels when given, checked
    backwards: ``(uv1 (K, 2), ok (K,) bool)``."""
    if not len(uv):
        return np.zeros((0, 2)), np.zeros(0, bool)
    p0 = uv.astype(np.float32).reshape(-1, 1, 2)
    lk = dict(
        winSize=(cfg.window_px, cfg.window_px),
        maxLevel=cfg.levels,
        criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01),
    )
    if guess is None:
        p1, st1, _ = cv2.calcOpticalFlowPyrLK(img0, img1, p0, None, **lk)
        pb, st2, _ = cv2.calcOpticalFlowPyrLK(img1, img0, p1, None, **lk)
    else:  # started at the guess; backwards from the start the forward pass corrected
        start = cv2.OPTFLOW_USE_INITIAL_FLOW
        g = guess.astype(np.float32).reshape(-1, 1, 2)
        p1, st1, _ = cv2.calcOpticalFlowPyrLK(img0, img1, p0, g.copy(), flags=start, **lk)
        back = p0 - (p1 - g)
        pb, st2, _ = cv2.calcOpticalFlowPyrLK(img1, img0, p1, back, flags=start, **lk)
    fb = np.linalg.norm((pb - p0).reshape(-1, 2), axis=1)
    h, w = img0.shape
    uv1 = p1.reshape(-1, 2).astype(float)
    ok = (
        (st1.ravel() == 1)
        & (st2.ravel() == 1)
        & (fb <= cfg.fb_px)
        & (uv1[:, 0] >= 0)
        & (uv1[:, 0] <= w - 1)
        & (uv1[:, 1] >= 0)
        & (uv1[:, 1] <= h - 1)
    )
    return uv1, ok


def refine_corners(img0: np.ndarray, img1: np.ndarray, uv0, uv1, ok, cfg: FlowSettings):
    """Least squares matching of the corners ``uv0`` (K, 2) of ``img0`` into ``img1``
    (uint8 (H, W)), started at ``uv1`` (K, 2) where ``ok`` (K,): ``(uv1 (K, 2), ok (K,))``
    with the matched points, and ``ok`` False where the match failed (with
    ``cfg.refine_drop``; else the start is kept there)."""
    from .lsm import match

    uv1, ok = uv1.copy(), ok.copy()
    k = np.flatnonzero(ok)
    if not len(k):
        return uv1, ok
    res = match(
        img0,
        img1,
        uv0[k],
        uv1[k],
        max_shift_px=cfg.refine_max_shift_px,
        max_sigma_px=cfg.refine_max_sigma_px,
    )
    good = res.status == 0
    uv1[k[good]] = res.uv[good]
    if cfg.refine_drop:
        ok[k[~good]] = False
    return uv1, ok


class FlowAnchors:
    """Corners lifted onto the last fitted frame, followed into the next on request.

    With ``settings.reference``, corners lifted onto the clicked frame
    (:meth:`set_reference`) are also matched from that frame's image straight into
    each frame asked for.

    Parameters
    ----------
    cameras : list (C) of Camera
    image : callable ``(camera index, frame) -> (H, W) uint8`` grey image
    settings : FlowSettings
    rays : list (C) of (H, W, 3) cached viewing rays, optional
    """

    def __init__(
        self,
        cameras: list[Camera],
        image,
        settings: FlowSettings | None = None,
        rays: list | None = None,
    ):
        self.cameras = list(cameras)
        self.image = image
        self.cfg = settings or FlowSettings()
        self.rays = rays if rays is not None else [camera_rays(c) for c in self.cameras]
        self.frame: int | None = None
        self._lifted: list = []
        self._cache: dict = {}
        self._followed: dict = {}  # frame -> per camera (uv, bone, q0) followed there
        self.reference = TextureReference(
            self.cameras,
            image,
            self.cfg,
            lambda img0, img1, uv: follow_corners(img0, img1, uv, self.cfg),
        )

    def clear(self) -> None:
        self.frame = None
        self._lifted = []
        self._cache = {}
        self._followed = {}
        self.reference.clear()

    def set_reference(
        self,
        skel: Skeleton,
        balls: Metaballs,
        theta,
        root,
        s,
        frame: int,
        foreground: list | None = None,
    ) -> None:
        """Lift every camera's corners of ``frame`` (the clicked one) onto the fitted
        body and keep them, with the images, as the texture reference."""
        pose = forward(skel, np.asarray(theta, float)[None], np.asarray(root, float)[None], s)
        lifted = []
        for c, cam in enumerate(self.cameras):
            fg = None if foreground is None else foreground[c]
            img = np.array(self.image(c, frame))
            ren = render_body(skel, balls, pose, s, cam, self.rays[c])
            uv, bone, q0 = lift_corners(
                skel, balls, theta, root, s, cam, img, fg, self.cfg, self.rays[c], ren=ren
            )
            if self.cfg.reference_parts is not None:
                on = np.isin(np.asarray(skel.bone_names)[bone], self.cfg.reference_parts)
                uv, bone, q0 = uv[on], bone[on], q0[on]
            lifted.append((img, uv, bone, q0, surface_tangents(skel, pose, cam, ren, uv, bone)))
        self.reference.start(skel, pose, lifted)

    def set(
        self,
        skel: Skeleton,
        balls: Metaballs,
        theta,
        root,
        s,
        frame: int,
        foreground: list | None = None,
    ) -> None:
        """Lift the corners of every camera's image of ``frame`` onto the fitted body
        (``foreground`` (C) of (H, W) bool or None per camera); with
        ``settings.persist`` the corners followed into ``frame`` keep their points."""
        followed = self._followed.get(frame) if self.cfg.persist else None
        matched = self.reference.matched.get(frame)
        self.clear()
        self.frame = frame
        pose = forward(skel, np.asarray(theta, float)[None], np.asarray(root, float)[None], s)
        rens = []
        for c, cam in enumerate(self.cameras):
            fg = None if foreground is None else foreground[c]
            ren = render_body(skel, balls, pose, s, cam, self.rays[c])
            rens.append(ren)
            self._lifted.append(
                lift_corners(
                    skel,
                    balls,
                    theta,
                    root,
                    s,
                    cam,
                    self.image(c, frame),
                    fg,
                    self.cfg,
                    self.rays[c],
                    None if followed is None else followed[c],
                    ren,
                )
            )
        if self.cfg.reference:
            self.reference.update(skel, pose, rens, matched)

    def observations(self, frame: int) -> FlowObs | None:
        """The lifted corners followed into ``frame`` (the stored frame ± 1), and the
        reference's matched there, or None."""
        if self.frame is None or abs(frame - self.frame) != 1:
            return None
        if frame in self._cache:
            return self._cache[frame]
        bone, q0, cam, uv, sig = [], [], [], [], []
        followed = []
        for c, (uv0, b, q) in enumerate(self._lifted):
            if not len(uv0):
                followed.append((uv0, b, q))
                continue
            img0, img1 = self.image(c, self.frame), self.image(c, frame)
            uv1, ok = follow_corners(img0, img1, uv0, self.cfg)
            if self.cfg.refine_lsm:
                uv1, ok = refine_corners(img0, img1, uv0, uv1, ok, self.cfg)
            followed.append((uv1[ok], b[ok], q[ok]))
            bone.append(b[ok])
            q0.append(q[ok])
            uv.append(uv1[ok])
            cam.append(np.full(int(ok.sum()), c))
            sig.append(np.full(int(ok.sum()), self.cfg.sigma_px))
        for c, b, q, u in self.reference.matches(self.frame, frame):
            bone.append(b)
            q0.append(q)
            uv.append(u)
            cam.append(np.full(len(b), c))
            sig.append(np.full(len(b), self.cfg.reference_sigma_px))
        obs = None
        if bone and sum(len(b) for b in bone):
            obs = FlowObs(
                self.cameras,
                np.concatenate(bone),
                np.concatenate(q0),
                np.concatenate(cam),
                np.concatenate(uv),
                np.concatenate(sig),
                self.cfg.robust_scale,
            )
        self._cache[frame] = obs
        self._followed[frame] = followed
        return obs
