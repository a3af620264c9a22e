"""One frame of the sequence fit: the pose solve, its retries and its quality record.

:class:`FrameFitter` holds what :func:`core.fit.fit_sequence` carries from frame to
frame — the current shape (``balls``, bone scales ``s``, metaball ``radii``), the
segmentation labels and the trajectories of the last fitted frame, the free-space
probes — and the per-frame results it fills in place.  Per frame
(:meth:`FrameFitter.fit_frame`): the points are *segmented* to body parts at the
predicted pose (:mod:`core.segment`), the pose is refined by weighted least squares
(:func:`core.fitting.fit`) with a prior on the angles (:meth:`FrameFitter.prior`: the
prediction, σ capped for stiff DOFs, fused with a prior towards the clicked posture),
parts with too few points or contour pairs *hidden* (:meth:`FrameFitter.hidden_dofs`);
segmented again and refined once more.  Then the recovery of :mod:`core.fit_search`
(the limb search, or an annealed refit from the best start), with contours the
silhouette retries (:mod:`core.fit_silhouette`), the quality judged by
:func:`core.fit_assess.assess_frame` and recorded (:meth:`FrameFitter.record`).  The
steps and their settings are described in :mod:`core.fit`.

Arrays: ``theta`` (F, n) radians; ``root`` (F, 3) world metres (Z up); a pose ``q``
(n + 3,) is ``[θ, root]``; points ``xyz`` (N, 3) world metres.
"""

from __future__ import annotations

import numpy as np

from .fit_assess import assess_frame
from .fit_chain import chain_prior
from .fit_contours import containment_parts
from .fit_depth import frame_depth_holds
from .fit_init import Initialisation
from .fit_search import explain_cost, recentred_starts, search_limbs
from .fit_silhouette import SilhouetteRetries
from .fit_trajectory import TrajectoryAnchors
from .fit_types import FramePoints, SequenceSettings, frame_observations
from .fit_whole_shape import has_outline
from .fitting import FitSettings, fit
from .free_space import FrameProbes
from .segment import carry_labels, no_labels, segment_points
from .skeleton import anchor_sigma, joint_positions, stiff_sigma


class FrameFitter(SilhouetteRetries):
    """The per-frame fits of :func:`core.fit.fit_sequence` and their results.

    Parameters
    ----------
    frames : list (F) of FramePoints — the observations of every frame
    init : Initialisation — the body and posture of the clicked frame
    cfg : SequenceSettings
    contours : list (F) of :class:`core.fit_contours.ContourFrame` (or None per frame),
        or None
    flow : :class:`core.fit_flow.FlowAnchors` or None
    cameras : list of :class:`core.camera.Camera` or None — for the free-space probes

    Attributes
    ----------
    balls, s, radii : the current shape (metaballs, bone scales (G,), radii (M, 3)
        metres); the sequence fit replaces them after its shape solves
    theta : (F, n) radians; root : (F, 3) metres — the stored poses
    q_sig : (F, n) σ of the angles; rmse : (F,) metres; conv, div, retried : (F,) bool;
    n_pts : (F,) int; inl, unexpl : (F,) shares; hid : (F, n) bool hidden DOFs;
    c_n : (F,) int contour pairs; c_rms : (F,) their RMS, pixels;
    cams_used : list (F) of dict — the per-frame results, filled in place
    msgs : list of str — the messages of diverged frames
    labels : the segmentation labels of the last accepted fit
    last_fitted : the last frame stored as fitted with points (-1: none)
    """

    def __init__(
        self,
        frames: list[FramePoints],
        init: Initialisation,
        cfg: SequenceSettings,
        contours: list | None = None,
        flow=None,
        cameras: list | None = None,
    ):
        self.frames, self.init, self.cfg = frames, init, cfg
        self.contours, self.flow = contours, flow
        nf = self.nf = len(frames)
        skel = self.skel = init.skeleton
        self.balls = init.metaballs.copy()
        n = self.n = skel.n_dof
        self.s, self.radii = init.s.copy(), self.balls.radii.copy()
        self.theta = np.zeros((nf, n))
        self.root = np.zeros((nf, 3))
        self.q_sig = np.full((nf, n), np.nan)
        self.rmse = np.full(nf, np.nan)
        self.conv = np.zeros(nf, bool)
        self.div = np.zeros(nf, bool)
        self.n_pts = np.zeros(nf, int)
        self.inl = np.zeros(nf)
        self.unexpl = np.full(nf, np.nan)
        self.retried = np.zeros(nf, bool)
        self.hid = np.zeros((nf, n), bool)
        self.c_n = np.zeros(nf, int)
        self.c_rms = np.full(nf, np.nan)
        self.cams_used: list[dict] = [{} for _ in range(nf)]
        self.msgs: list[str] = []
        self.pose_cfg = FitSettings(**{**cfg.fit.__dict__, "max_nfev": cfg.max_nfev})
        self.labels = no_labels()
        self.stiff = stiff_sigma(skel)
        self.anchor = anchor_sigma(skel)
        self.chain = (
            None
            if cfg.sigma_trunk_chain is None
            else chain_prior(skel, init.theta, cfg.sigma_trunk_chain)
        )
        self.dof_bone = skel.dof_bones()
        self.anchors = TrajectoryAnchors()  # the trajectories of the last fitted frame
        self.frame_probes = FrameProbes(frames, cameras, cfg.free_space)
        self.last_fitted = -1  # the last frame stored as fitted with points (recentred_starts)
        self.up = np.subtract(
            *joint_positions(skel, init.theta, init.root_xyz, init.s)[
                [skel.joint_index("neck"), skel.joint_index("pelvis")]
            ]
        )  # the body upright

    @property
    def segment_radii(self) -> np.ndarray:
        """(M, 3) radii that label the points (:func:`core.segment.segment_points`): the
        initial shape's (``cfg.segment_initial_radii``), else the fitted ones.

        The per-part shape solve lets a part's metaballs grow over a neighbour whose
        points it was given; labelling with the grown shape then hands it all of them
        (the head takes the whole neck), and the pose bends to put them on it.
        """
        return self.balls.radii if self.cfg.segment_initial_radii else self.radii

    def stored_labels(self, g):
        """Frame g's points segmented to bones (N,) at its stored pose (−1: left out;
        ``cfg.segment_max_dist`` and ``segment_margin``): what the shape solves take."""
        part, _ = segment_points(
            self.frames[g].xyz,
            self.skel,
            self.balls,
            self.theta[g],
            self.root[g],
            self.s,
            self.segment_radii,
            self.cfg.segment_max_dist,
            self.cfg.segment_margin,
        )
        return part

    def cframe(self, f):
        """Frame f's :class:`core.fit_contours.ContourFrame`, or None."""
        return None if self.contours is None else self.contours[f]

    def hidden_dofs(self, xyz, q, max_dist, cf=None):
        """(n,) bool: DOFs of parts with fewer than ``min_part_points`` points within
        ``max_dist`` of them at pose q (counted without the ambiguity margin: a limb
        beside the trunk is seen even where its points are not used) and, with contours
        ``cf``, fewer than its ``min_part_matches`` contour pairs there."""
        if len(xyz):
            part, _ = segment_points(
                xyz,
                self.skel,
                self.balls,
                q[: self.n],
                q[self.n :],
                self.s,
                self.segment_radii,
                max_dist,
                0.0,
            )
            cnt = np.bincount(part[part >= 0], minlength=len(self.skel.bone_names))
        else:
            cnt = np.zeros(len(self.skel.bone_names), int)
        hidden = cnt[self.dof_bone] < self.cfg.min_part_points
        if cf is not None:
            # parts that the points observe: their contour pairs weigh less (σ × scale)
            cf.part_scale = np.where(cnt >= self.cfg.min_part_points, cf.cfg.textured_scale, 1.0)
            cf.containment_parts = containment_parts(
                cnt, len(xyz) >= self.cfg.min_points, self.cfg.min_part_points, cf.cfg
            )
            cf.freeze(
                self.skel, self.balls.copy(radii=self.radii), q[: self.n], q[self.n :], self.s
            )
            if len(xyz) < self.cfg.min_points or cf.cfg.unhide:
                # beside points, one view's contours do not un-hide a part (its depth)
                views = cf.cfg.unhide_views if len(xyz) >= self.cfg.min_points else 1
                hidden &= (
                    cf.part_counts(len(self.skel.bone_names), views)[self.dof_bone]
                    < cf.cfg.min_part_matches
                )
        return hidden

    def prior(self, hidden, th_pred, sig_pred, th_hold):
        """Target and σ of the prior on the angles: the prediction, σ capped for stiff
        DOFs; the DOFs of parts with too few points (hidden) follow the (damped)
        prediction, or are held at ``th_hold`` (the previous frame, when given), with σ
        ``sigma_hidden``; fused with a prior towards the initial posture (anchored DOFs,
        and hidden parts, which drift back to the clicked posture instead of
        wandering)."""
        sig = np.minimum(sig_pred, self.stiff)
        target = th_pred if th_hold is None else np.where(hidden, th_hold, th_pred)
        sig = np.where(hidden, np.minimum(sig, self.cfg.sigma_hidden), sig)
        sig_a = np.where(hidden, np.minimum(self.anchor, self.cfg.sigma_hidden_anchor), self.anchor)
        w1, w2 = 1.0 / sig**2, 1.0 / sig_a**2
        return (w1 * target + w2 * self.init.theta) / (w1 + w2), 1.0 / np.sqrt(w1 + w2)

    def search_start(self, f, cands):
        """Of the candidate poses (k, n+3), the one whose body explains frame f's points
        best (:func:`core.fit_search.explain_cost`)."""
        cands = np.atleast_2d(cands)
        if len(cands) == 1 or not len(self.frames[f].xyz):
            return cands[0].copy()
        cost = explain_cost(
            self.frames[f].xyz,
            self.skel,
            self.balls,
            self.s,
            self.radii,
            cands[:, : self.n],
            cands[:, self.n :],
            self.cfg.search_tau,
            probes=self.frame_probes(f),
        )
        return cands[int(np.argmin(cost))].copy()

    def one_frame(self, f, q_pred, sig_pred, joints=None, q_hold=None, anneal=False):
        """Pose-only fit of frame f from ``q_pred`` (n+3,), which is also the prior's
        target; returns ``(q, FitResult, ok, part or message, labels)``.

        Plain: segment, fit, segment again, fit (``cfg.segment_max_dist`` and the
        robust scale of ``cfg.fit``).  ``anneal``: the stages of ``cfg.anneal`` —
        wide segmentation and a soft robust knee first, narrowing — and, after the
        first stage has brought the trunk near its points, every limb placed by
        :func:`core.fit_search.search_limbs` (its new angles become the prior's
        target)."""
        pts = self.frames[f]
        cf = self.cframe(f)
        lab = self.labels
        stages = (
            self.cfg.anneal
            if anneal
            else ((self.cfg.segment_max_dist, self.cfg.fit.robust_scale),)
            * (2 if self.cfg.resegment else 1)
        )
        if cf is not None and len(pts.xyz) < self.cfg.min_points:  # contours alone: no
            stages = stages[:1]  # segmentation to redo (they re-pair every round)
        q, target_q = q_pred.copy(), q_pred.copy()
        r = part = None
        traj = (
            self.anchors.observations(
                pts.xyz, pts.sigma, pts.ids, self.cfg.traj_slip_m, self.cfg.traj_robust
            )
            if self.cfg.trajectories
            else None
        )
        for k, (max_dist, knee) in enumerate(stages):
            if anneal and k == 1 and self.cfg.search:
                q[: self.n] = search_limbs(
                    pts.xyz,
                    self.skel,
                    self.balls,
                    self.s,
                    self.radii,
                    q[: self.n],
                    q[self.n :],
                    tau=self.cfg.search_tau,
                    probes=self.frame_probes(f),
                ).theta
                target_q = q.copy()
            if len(pts.xyz):
                part, _ = segment_points(
                    pts.xyz,
                    self.skel,
                    self.balls,
                    q[: self.n],
                    q[self.n :],
                    self.s,
                    self.segment_radii,
                    max_dist,
                    self.cfg.segment_margin,
                )
                part, lab = carry_labels(part, pts.ids, lab)
            else:
                part = np.zeros(0, int)
            if (part >= 0).sum() < self.cfg.min_points and cf is None:
                if r is None:
                    return (
                        None,
                        None,
                        False,
                        f"frame {f}: only {(part >= 0).sum()} usable points",
                        lab,
                    )
                break
            hidden = self.hidden_dofs(pts.xyz, q, max_dist, cf)
            target, sig = self.prior(
                hidden, target_q[: self.n], sig_pred, None if q_hold is None else q_hold[: self.n]
            )
            o = frame_observations(pts, part, target, sig, self.n, joints)
            o.contours = cf
            o.linear_prior = self.chain
            if cf is not None and len(pts.xyz) < self.cfg.min_points:
                q_ref = target_q if q_hold is None else q_hold  # the previous frame
                o.depth = frame_depth_holds(
                    self.skel, cf, hidden, q_ref[: self.n], q_ref[self.n :], self.s
                )
            o.trajectory = traj
            if self.flow is not None and (
                len(pts.xyz) < self.cfg.min_points or not self.flow.cfg.without_points_only
            ):
                o.flow = self.flow.observations(f)
            stage_cfg = (
                self.pose_cfg
                if knee == self.pose_cfg.robust_scale
                else FitSettings(**{**self.pose_cfg.__dict__, "robust_scale": knee})
            )
            if cf is not None and stage_cfg.irls_rounds < cf.cfg.rounds:
                stage_cfg = FitSettings(**{**stage_cfg.__dict__, "irls_rounds": cf.cfg.rounds})
            r = fit(
                self.skel,
                self.balls,
                o,
                q[: self.n],
                q[self.n :],
                self.s,
                self.radii,
                solve="pose",
                settings=stage_cfg,
            )
            q = np.concatenate([r.theta, r.root_xyz])
        return q, r, True, part, lab

    def assess(self, f, res):
        """Quality of a fitted frame, without side effects: ``(ok, reasons, stats)``."""
        return assess_frame(
            res,
            self.skel,
            self.balls,
            self.radii,
            self.s,
            self.frames[f].xyz,
            self.cframe(f),
            lambda: self.frame_probes(f),
            self.cfg,
        )

    def record(self, f, res, ok, why, stats):
        """Write the quality of frame f (and the message of a diverged one); commit the
        segmentation labels of an accepted fit."""
        if stats is not None:
            self.n_pts[f], self.inl[f], self.rmse[f], self.q_sig[f] = (
                stats["n"],
                stats["inl"],
                stats["rmse"],
                stats["sig"],
            )
            self.unexpl[f] = stats["unexplained"]
            if stats["contour"] is not None:
                self.c_n[f], self.c_rms[f] = stats["contour"]["n"], stats["contour"]["rms_px"]
        if ok:
            self.conv[f] = stats["conv"]
            self.labels = res[4]
            if self.cframe(f) is not None:
                self.cams_used[f] = self.cframe(f).cameras_used(self.skel)
        else:
            self.msgs.append(
                f"frame {f}: {why}: marked diverged"
                if stats is not None
                else f"{why}: marked diverged"
            )

    def fit_frame(
        self, f, q_pred, sig_pred, alternatives=(), joints=None, q_hold=None, contour_starts=()
    ):
        """Fit frame f: the plain fit from the prediction, then

        * when it is accepted, the limb search (:func:`core.fit_search.search_limbs`)
          from its pose: a limb that a better place explains more points at is moved
          there and the frame refitted from it (a limb lost while hidden, or one that
          moved faster than the prediction), kept when it explains the points better
          and the outline about as well (:meth:`outline_agrees`);
        * when it fails or leaves more than ``cfg.retry_unexplained`` of the points far
          from the body, an annealed fit (:meth:`one_frame` ``anneal``) from the best
          of the prediction and the alternatives;

        the accepted fit of lowest explain cost wins.  A frame without points (contours
        alone) takes the silhouette retries (:meth:`contour_fit`); it is fitted the same
        way from each pose of ``contour_starts`` too (e.g. the previous frame's and its
        undamped extrapolation, where a fast limb outran the damped prediction); such a
        fit replaces the prediction's when its body disagrees with the foreground at a
        share ``cfg.contour_start_margin`` fewer pixels, and of those the fewest win.
        Returns ``(ok, q)`` with q the fitted pose, or the prediction when no fit is
        accepted."""
        res = self.one_frame(f, q_pred, sig_pred, joints, q_hold)
        ok, why, st = self.assess(f, res)
        search = self.cfg.search and len(self.frames[f].xyz) >= self.cfg.min_points  # needs points
        if search and ok and st["unexplained"] <= self.cfg.retry_unexplained:
            sr = search_limbs(
                self.frames[f].xyz,
                self.skel,
                self.balls,
                self.s,
                self.radii,
                res[0][: self.n],
                res[0][self.n :],
                tau=self.cfg.search_tau,
                min_gain=self.cfg.search_min_gain,
                probes=self.frame_probes(f),
            )
            if sr.moved:
                q1 = res[0].copy()
                q1[: self.n] = sr.theta
                res2 = self.one_frame(f, q1, sig_pred, joints, q_hold)
                ok2, why2, st2 = self.assess(f, res2)
                if ok2 and st2["cost"] < st["cost"] and self.outline_agrees(f, res2[0], res[0]):
                    res, ok, why, st = res2, ok2, why2, st2
                    self.retried[f] = True
        elif search:
            # also the prediction moved onto the points: after frames that failed, the
            # person may have walked on while the prediction stayed behind
            cands = np.stack([q_pred, *alternatives])
            if self.cfg.recentre and self.last_fitted >= 0:
                cands = np.concatenate(
                    [
                        cands,
                        recentred_starts(
                            self.frames[f].xyz,
                            q_pred,
                            self.frames[self.last_fitted].xyz,
                            self.root[self.last_fitted],
                            self.up,
                        ),
                    ]
                )
            q0 = self.search_start(f, cands)
            res2 = self.one_frame(f, q0, sig_pred, joints, q_hold, anneal=True)
            ok2, why2, st2 = self.assess(f, res2)
            if ok2 and (not ok or st2["cost"] < st["cost"]):
                res, ok, why, st = res2, ok2, why2, st2
                self.retried[f] = True
        if (
            search
            and ok
            and self.cfg.silhouette_search
            and self.cfg.silhouette_search_points
            and has_outline(self.cframe(f))
        ):
            res, ok, why, st = self.silhouette_retry(f, res, st, sig_pred, joints, q_hold)
        elif not search and self.cfg.silhouette_search and self.cframe(f) is not None:
            res, ok, why, st = self.contour_fit(
                f, res, ok, why, st, q_pred, sig_pred, joints, q_hold
            )
            # the prediction's fit is replaced only by a share ``contour_start_margin``
            # fewer pixels; past that, the fewest win
            bar = (
                (1.0 - self.cfg.contour_start_margin) * self.disagreement(f, res[0])
                if ok
                else np.inf
            )
            retried = self.retried[f]
            for q0 in contour_starts:
                res2 = self.one_frame(f, q0, sig_pred, joints, q_hold)
                ok2, why2, st2 = self.assess(f, res2)
                res2, ok2, why2, st2 = self.contour_fit(
                    f, res2, ok2, why2, st2, q0, sig_pred, joints, q_hold
                )
                d2 = self.disagreement(f, res2[0]) if ok2 else np.inf
                if d2 < bar:
                    res, ok, why, st = res2, ok2, why2, st2
                    bar, retried = d2, True
            self.retried[f] = retried
        self.record(f, res, ok, why, st)
        if ok:
            self.hid[f] = self.hidden_dofs(
                self.frames[f].xyz, res[0], self.cfg.segment_max_dist, self.cframe(f)
            )
        return ok, (res[0] if ok else q_pred)

    def store(self, f, q, ok):
        """Store pose q (n + 3,) as frame f's, diverged unless ``ok``."""
        self.theta[f], self.root[f] = q[: self.n], q[self.n :]
        self.div[f] = not ok
        if ok and len(self.frames[f].xyz) >= self.cfg.min_points:
            self.last_fitted = f

    def keep_trajectories(self, f):
        """Keep frame f's trajectories in their parts' frames (none after a diverged
        frame) for the next frame's rigid-motion observations."""
        pts = self.frames[f]
        if self.flow is not None:
            near = [g for g in (f - 1, f + 1) if 0 <= g < self.nf]
            if self.div[f] or (
                self.flow.cfg.without_points_only
                and all(len(self.frames[g].xyz) >= self.cfg.min_points for g in near)
            ):
                self.flow.clear()  # (no neighbour will use the flow)
            else:
                cf = self.cframe(f)
                self.flow.set(
                    self.skel,
                    self.balls.copy(radii=self.radii),
                    self.theta[f],
                    self.root[f],
                    self.s,
                    f,
                    None if cf is None else cf.masks(),
                )
        if not self.cfg.trajectories or self.div[f] or pts.ids is None:
            self.anchors.clear()
            return
        part = carry_labels(np.full(len(pts.xyz), -1), pts.ids, self.labels)[0]
        self.anchors.set(
            self.skel, self.theta[f], self.root[f], self.s, pts.xyz, pts.sigma, pts.ids, part
        )
