"""The silhouette retries of one frame's fit: the body moved onto the foreground.

:class:`SilhouetteRetries` is the part of :class:`core.fit_frame.FrameFitter` that
weighs a frame's fit against the cameras' foreground masks:

* :meth:`~SilhouetteRetries.recentre_retry` — contours alone, a failed frame refitted
  with the root re-centred on the foreground;
* :meth:`~SilhouetteRetries.silhouette_retry` — every limb placed where it best
  explains the foreground (:func:`core.silhouette_search.search_limbs_silhouette`) and
  the frame refitted from there, kept when the body disagrees with the foreground at
  fewer pixels;
* :meth:`~SilhouetteRetries.contour_fit` — both, for a frame without points;
* :meth:`~SilhouetteRetries.outline_agrees` — whether a refit the points prefer
  (the limb search of :mod:`core.fit_search`) keeps the outline about as well;
* :meth:`~SilhouetteRetries.disagreement` — the pixels where a pose's body and the
  foreground disagree, summed over the cameras.

It uses the fitter's state and per-frame fit: ``skel``, ``balls``, ``radii``, ``s``,
``n``, ``cfg``, ``frames``, ``retried``, :meth:`cframe`, :meth:`frame_probes`,
:meth:`one_frame` and :meth:`assess`.

Arrays: a pose ``q`` (n + 3,) is ``[θ radians, root metres]``.
"""

from __future__ import annotations

import numpy as np

from .fit_search import keeps_points
from .fit_whole_shape import has_outline
from .silhouette_search import (
    folds,
    recentre_root,
    search_limbs_silhouette,
    silhouette_disagreement,
)


class SilhouetteRetries:
    """The foreground-mask retries of :class:`core.fit_frame.FrameFitter` (a mixin; see
    the module text for what it needs of the fitter)."""

    def recentre_retry(self, f, res, ok, why, st, q_pred, sig_pred, joints, q_hold):
        """Contours alone, a frame that failed: the root moved to centre the body on
        the foreground (:func:`core.silhouette_search.recentre_root`, from the fit or
        the prediction) and the frame refitted from there; the first refit accepted
        wins.  Returns ``(res, ok, why, stats)``."""
        cf = self.cframe(f)
        body = self.balls.copy(radii=self.radii)
        starts = [q_pred]
        if res[0] is not None and np.all(np.isfinite(res[0])):
            starts.insert(0, res[0])
        for q0 in starts:
            q1 = q0.copy()
            q1[self.n :] = recentre_root(
                self.skel, body, q0[: self.n], q0[self.n :], self.s, cf.cameras, cf.grids()
            )
            res2 = self.one_frame(f, q1, sig_pred, joints, q_hold)
            ok2, why2, st2 = self.assess(f, res2)
            if ok2:
                self.retried[f] = True
                return res2, ok2, why2, st2
        return res, ok, why, st

    def silhouette_retry(self, f, res, st, sig_pred, joints, q_hold, unfold=False, restore=False):
        """Every limb placed where it best explains the frame's foreground
        (:func:`search_limbs_silhouette`; with points, a move vetoed by ``keeps_points``)
        and the frame refitted from there, the moved DOFs' hold and prior following the
        search; the refit is kept when it is accepted and the body's projection disagrees
        with the foreground at fewer pixels.  ``unfold``: a folded knee or elbow is also
        tried straightened (:func:`search_limbs_silhouette`), and a search that folds
        one (``cfg.contour_no_fold``) is refitted beside the search without the fold,
        the one disagreeing at fewer pixels kept.  Returns ``(res, ok, why, stats)``."""
        q = res[0]
        xyz = self.frames[f].xyz
        veto = (
            keeps_points(
                xyz,
                self.skel,
                self.balls,
                self.s,
                self.radii,
                q[self.n :],
                self.cfg.search_tau,
                self.frame_probes(f),
            )
            if len(xyz) >= self.cfg.min_points
            else None
        )
        search = dict(allowed=veto, unfold=unfold)
        if veto is not None:
            search["twist"] = self.cfg.silhouette_points_twist
        found = [search_limbs_silhouette(*self._search_args(f, q), **search)]
        if unfold and self.cfg.contour_no_fold and folds(self.skel, q[: self.n], found[0].theta):
            # a fold the search made is weighed against the search without it
            found.append(search_limbs_silhouette(*self._search_args(f, q), no_fold=True, **search))
        best, best_dis = None, self.disagreement(f, q)
        for sr in found:
            if not sr.moved:
                continue
            q1 = q.copy()
            q1[: self.n] = sr.theta
            hold = None
            if q_hold is not None:
                hold = q_hold.copy()
                moved = sr.theta != q[: self.n]
                hold[: self.n][moved] = sr.theta[moved]
            res2 = self.one_frame(f, q1, sig_pred, joints, hold)
            ok2, why2, st2 = self.assess(f, res2)
            dis = self.disagreement(f, res2[0]) if ok2 else np.inf
            if dis < best_dis:
                best, best_dis, best_moved = (res2, ok2, why2, st2), dis, sr.theta != q[: self.n]
        if best is None:
            return res, True, "", st
        if restore:
            # the moved limbs back at the start, on the rest of the body as refitted
            q2 = best[0][0].copy()
            q2[: self.n][best_moved] = q[: self.n][best_moved]
            res3 = self.one_frame(f, q2, sig_pred, joints, q_hold)
            ok3, why3, st3 = self.assess(f, res3)
            if ok3 and self.disagreement(f, res3[0]) < best_dis:
                best = (res3, ok3, why3, st3)
        self.retried[f] = True
        return best

    def _search_args(self, f, q):
        """The positional arguments of :func:`search_limbs_silhouette` for frame f from
        pose q (n + 3,)."""
        cf = self.cframe(f)
        body = self.balls.copy(radii=self.radii)
        return self.skel, body, self.s, q[: self.n], q[self.n :], cf.cameras, cf.masks()

    def contour_fit(self, f, res, ok, why, st, q_start, sig_pred, joints, q_hold):
        """The silhouette retries of a frame without points, after its plain fit from
        ``q_start``: recentred (:meth:`recentre_retry`) when it failed, then every limb
        placed on the foreground (:meth:`silhouette_retry`, a folded hinge unfolded with
        ``cfg.contour_unfold``).  Returns
        ``(res, ok, why, stats)``."""
        if not ok:
            res, ok, why, st = self.recentre_retry(
                f, res, ok, why, st, q_start, sig_pred, joints, q_hold
            )
        if ok:
            res, ok, why, st = self.silhouette_retry(
                f,
                res,
                st,
                sig_pred,
                joints,
                q_hold,
                self.cfg.contour_unfold,
                self.cfg.contour_restore,
            )
        return res, ok, why, st

    def outline_agrees(self, f, q_new, q_old):
        """Whether pose ``q_new`` disagrees with frame f's foreground at no more than
        ``1 + cfg.search_outline_margin`` times the pixels ``q_old`` does (True when the
        check is off, ``search_outline_margin`` None, or the frame has no outline)."""
        margin = self.cfg.search_outline_margin
        if margin is None or not has_outline(self.cframe(f)):
            return True
        return self.disagreement(f, q_new) <= (1.0 + margin) * self.disagreement(f, q_old)

    def disagreement(self, f, q):
        """Pixels where pose q's body and frame f's foreground disagree (all cameras)."""
        cf = self.cframe(f)
        body = self.balls.copy(radii=self.radii)
        return silhouette_disagreement(
            self.skel, body, q[: self.n], q[self.n :], self.s, cf.cameras, cf.grids()
        )
