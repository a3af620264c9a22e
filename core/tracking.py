"""Spatial + temporal LSM tracking of surface points, trajectory filters, regeneration.

Per frame i -> i+1 (D'Apuzzo et al. 1999, section 2.4), for all live points and
cameras at once:

1. linear prediction ``uv_i + (uv_i - uv_{i-1})`` in every camera;
2. NCC search in a box around it (frame i template, frame i+1 image);
3. temporal LSM from frame i to frame i+1, started at the NCC peak;
4. spatial LSM at frame i+1 from the reference camera into the others, started at
   the temporal results (or, where a camera lost the point, at the projection of the
   predicted 3-D point: that camera is re-acquired);
5. a camera's temporal match is accepted unless the spatial match converged more than
   ``agree_px`` away from it (a failed spatial match does not veto: the forward
   intersection checks the geometry); a camera without a temporal match is
   re-acquired where the spatial match exists; a point lives on while two or more
   cameras are accepted and the forward intersection reprojects within
   ``max_rms_px``.

Beyond the paper, every ``regen_every`` frames the surface is grown again from the
live points (:func:`core.surface.measure_surface`) over grid cells that no live point
covers: lost points are regenerated and newly visible surface is seeded.

:func:`filter_trajectories` applies the paper's filters afterwards: thresholds on
velocity and acceleration, and local uniformity (velocity against the median velocity
of the spatial neighbours over frames i-1..i+1; the median instead of the mean keeps a
false neighbour from hiding itself); flagged trajectories are truncated before their
first bad frame and removed when too little remains.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .camera import Camera
from .intersect import triangulate
from .lsm import ImageStack, match
from .ncc import search
from .surface import Surface, measure_surface


@dataclass
class Tracks:
    """Trajectories of P points over F frames in C cameras (NaN where not tracked).

    Attributes
    ----------
    xyz : ndarray, shape (F, P, 3)
        World positions, metres.
    uv : ndarray, shape (F, P, C, 2)
        Image positions, pixels.
    sigma_xyz : ndarray, shape (F, P, 3)
        Standard deviations of ``xyz`` from the forward intersection, metres.
    start : ndarray, shape (P,), int
        Frame where each trajectory starts (0 for the surface measured at frame 0,
        later for regenerated / new points).
    fps : float
    """

    xyz: np.ndarray
    uv: np.ndarray
    sigma_xyz: np.ndarray
    start: np.ndarray
    fps: float

    @property
    def alive(self) -> np.ndarray:
        """(F, P) bool: the point has a 3-D position at that frame."""
        return np.all(np.isfinite(self.xyz), axis=2)

    def velocity(self) -> np.ndarray:
        """(F, P, 3) m/s by central differences (one-sided at the ends), NaN where unknown."""
        return _derivative(self.xyz, self.fps)

    def acceleration(self) -> np.ndarray:
        """(F, P, 3) m/s² (second differences), NaN where unknown."""
        a = np.full_like(self.xyz, np.nan)
        a[1:-1] = (self.xyz[2:] - 2 * self.xyz[1:-1] + self.xyz[:-2]) * self.fps ** 2
        return a


def _derivative(x: np.ndarray, fps: float) -> np.ndarray:
    v = np.full_like(x, np.nan)
    v[1:-1] = (x[2:] - x[:-2]) * (fps / 2.0)
    fwd = (x[1:] - x[:-1]) * fps
    v[1:-1] = np.where(np.isfinite(v[1:-1]), v[1:-1],
                       np.where(np.isfinite(fwd[1:]), fwd[1:], fwd[:-1]))
    v[0], v[-1] = fwd[0], fwd[-1]
    return v


def track(frames, cameras: list[Camera], surface: Surface, n_frames: int, fps: float, *,
          half: int = 6, ncc_radius: int = 5, first_radius: int = 14,
          agree_px: float = 0.5, max_rms_px: float = 1.0,
          regen_every: int = 5, step: int = 2, progress=None,
          log: list | None = None) -> Tracks:
    """Track the surface points through ``n_frames`` frames.

    Parameters
    ----------
    frames : callable ``frames(i) -> list of C grey images``
        Images of frame i in camera order; a camera whose image is missing may give
        ``None`` (its points are then not matched there in that frame).
    cameras : list of Camera, length C
    surface : Surface
        Points measured at frame 0 (:func:`core.surface.measure_surface`).
    ncc_radius, first_radius : int
        NCC search box half widths with a velocity prediction and without one, pixels.
    regen_every : int
        Regenerate / seed new points every this many frames (0: never).
    log : list, optional
        Receives one dict per frame step with the counts of (point, camera) pairs
        through each stage (``seen``, ``ncc_ok``, ``temporal_ok``, ``spatial_ok``,
        ``agree``) and of points (``live_before``, ``live_after``, ``regenerated``).

    Returns
    -------
    Tracks
    """
    c = len(cameras)
    ref = surface.ref
    p0 = len(surface)
    uv_hist = [surface.uv.copy()]                    # per frame (P, C, 2)
    xyz_hist = [surface.xyz.copy()]
    sig_hist = [np.sqrt(np.abs(np.diagonal(surface.cov, axis1=1, axis2=2)))]
    start = np.zeros(p0, int)
    aff_sp = surface.affine.copy()                   # spatial affine ref -> camera
    prev = _stack(frames(0), cameras, 0)
    for i in range(n_frames - 1):
        nxt = _stack(frames(i + 1), cameras, i + 1)
        stage: dict = {}
        uv_i = uv_hist[-1]
        uv_im1 = uv_hist[-2] if len(uv_hist) > 1 else uv_i
        n = len(uv_i)
        vel = np.where(np.isfinite(uv_im1), uv_i - uv_im1, 0.0)
        pred = uv_i + vel
        live = np.all(np.isfinite(xyz_hist[-1]), axis=1)
        seen = np.all(np.isfinite(uv_i), axis=2) & live[:, None]
        pi, ci = np.nonzero(seen)
        # Temporal: NCC then LSM frame i -> i+1, every (point, camera) in one call.
        uv_t = np.full((n, c, 2), np.nan)
        if len(pi):
            # No velocity yet at the first step (or for a new point): a wider box.
            fresh = ~np.all(np.isfinite(uv_im1[pi, ci]), axis=1) | (len(uv_hist) == 1)
            rad = first_radius if np.any(fresh) else ncc_radius
            nc = search(prev.stack, nxt.stack, uv_i[pi, ci], pred[pi, ci], half=half,
                        radius=rad, template_index=ci, search_index=ci, min_score=0.6)
            st = np.where(nc.ok[:, None], nc.uv, pred[pi, ci])
            valid = nxt.valid[ci] & prev.valid[ci]
            rt = match(prev.stack, nxt.stack, uv_i[pi, ci], st, half=half,
                       template_index=ci, search_index=ci, max_shift_px=3.0)
            ok_t = rt.ok & valid
            uv_t[pi[ok_t], ci[ok_t]] = rt.uv[ok_t]
            if log is not None:
                stage = {"seen": len(pi), "ncc_ok": int(nc.ok.sum()),
                         "ncc_status": np.bincount(nc.status, minlength=6).tolist(),
                         "temporal_ok": int(ok_t.sum()),
                         "temporal_status": np.bincount(rt.status, minlength=8).tolist()}
        # Spatial LSM at i+1 from the reference camera (or the first temporally ok one).
        has_t = np.all(np.isfinite(uv_t), axis=2)
        tcam = np.where(has_t[:, ref], ref, np.argmax(has_t, axis=1))
        anchor = has_t[np.arange(n), tcam] & live
        # Start in cameras without a temporal match: the predicted 3-D point projected.
        xyz_pred = xyz_hist[-1] + (xyz_hist[-1] - xyz_hist[-2] if len(xyz_hist) > 1
                                   else 0.0)
        xyz_pred = np.where(np.isfinite(xyz_pred), xyz_pred, xyz_hist[-1])
        proj = np.stack([cam.project(xyz_pred) for cam in cameras], axis=1)
        start_s = np.where(has_t[..., None], uv_t, proj)
        qi, qc = np.nonzero(anchor[:, None] & (np.arange(c)[None] != tcam[:, None])
                            & np.all(np.isfinite(start_s), axis=2))
        uv_acc = np.full((n, c, 2), np.nan)
        uv_acc[anchor, tcam[anchor]] = uv_t[anchor, tcam[anchor]]
        if len(qi):
            tc = tcam[qi]
            aff0 = np.where((tc == ref)[:, None, None], aff_sp[qi, qc], np.eye(2))
            rs = match(nxt.stack, nxt.stack, uv_t[qi, tc], start_s[qi, qc], half=half,
                       affine=aff0, template_index=tc, search_index=qc, max_shift_px=3.0)
            d = np.linalg.norm(rs.uv - uv_t[qi, qc], axis=1)
            # A temporal match is vetoed only by a spatial match that converged elsewhere;
            # a failed spatial match (occlusion edge, weak texture in that view) leaves
            # the check to the forward intersection.  Re-acquisitions need the spatial.
            ht = has_t[qi, qc]
            agree = nxt.valid[qc] & np.where(ht, ~rs.ok | (d < agree_px), rs.ok)
            use_uv = np.where(has_t[qi, qc][:, None], uv_t[qi, qc], rs.uv)
            uv_acc[qi[agree], qc[agree]] = use_uv[agree]
            if log is not None:
                stage.update(spatial_ok=int(rs.ok.sum()), agree=int(agree.sum()),
                             with_t=int(has_t[qi, qc].sum()),
                             with_t_ok=int((rs.ok & has_t[qi, qc]).sum()),
                             spatial_status=np.bincount(rs.status, minlength=8).tolist(),
                             disagree_d=np.percentile(d[rs.ok & has_t[qi, qc]], [50, 90, 99])
                             .round(3).tolist() if np.any(rs.ok & has_t[qi, qc]) else [])
            upd = agree & (tc == ref)
            aff_sp[qi[upd], qc[upd]] = rs.affine[upd]
        inter = triangulate(cameras, uv_acc, sigma_px=0.05)
        good = inter.ok & (inter.rms < max_rms_px) & (np.sum(np.isfinite(uv_acc[..., 0]), 1) >= 2)
        uv_new = np.where(good[:, None, None], uv_acc, np.nan)
        xyz_new = np.where(good[:, None], inter.xyz, np.nan)
        sig_new = np.where(good[:, None], inter.sigma, np.nan)
        if log is not None:
            stage.update(live_before=int(live.sum()), live_after=int(good.sum()),
                         tri_fail=int((np.sum(np.isfinite(uv_acc[..., 0]), 1) >= 2).sum()
                                      - good.sum()))
            log.append(stage)
        uv_hist.append(uv_new)
        xyz_hist.append(xyz_new)
        sig_hist.append(sig_new)
        # Regenerate lost points and seed newly visible surface.
        if regen_every and (i + 1) % regen_every == 0 and good.any():
            occ = uv_new[good, ref]
            seeds = uv_new[good][:: max(1, int(good.sum()) // 20)]
            seeds = seeds[np.all(np.isfinite(seeds[:, ref]), axis=1)]
            if len(seeds) and nxt.valid.all():
                new = measure_surface(nxt.stack, cameras, seeds, ref=ref, step=step,
                                      half=half, occupied_uv=occ)
                if len(new):
                    k = len(new)
                    uv_hist = [_pad(u, k) for u in uv_hist]
                    xyz_hist = [_pad(x, k) for x in xyz_hist]
                    sig_hist = [_pad(s, k) for s in sig_hist]
                    uv_hist[-1][-k:] = new.uv
                    xyz_hist[-1][-k:] = new.xyz
                    sig_hist[-1][-k:] = np.sqrt(np.abs(np.diagonal(new.cov, axis1=1, axis2=2)))
                    start = np.concatenate([start, np.full(k, i + 1)])
                    aff_sp = np.concatenate([aff_sp, new.affine])
        prev = nxt
        if progress is not None:
            alive = int(np.all(np.isfinite(xyz_hist[-1]), axis=1).sum())
            progress.update(i + 1, n_frames - 1, f"tracking: frame {i + 1}, {alive} points")
    return Tracks(xyz=np.stack(xyz_hist), uv=np.stack(uv_hist), sigma_xyz=np.stack(sig_hist),
                  start=start, fps=float(fps))


def _pad(a: np.ndarray, k: int) -> np.ndarray:
    return np.concatenate([a, np.full((k,) + a.shape[1:], np.nan)])


@dataclass
class _Frame:
    stack: ImageStack
    valid: np.ndarray     # (C,) bool: the camera has an image in this frame


def _stack(images, cameras: list[Camera], i: int) -> _Frame:
    valid = np.array([im is not None for im in images])
    if len(images) != len(cameras):
        raise ValueError(f"frame {i}: {len(images)} images for {len(cameras)} cameras")
    if not valid.any():
        raise ValueError(f"frame {i}: no camera has an image")
    shape = next(im for im in images if im is not None).shape
    ims = [im if im is not None else np.zeros(shape, np.uint8) for im in images]
    return _Frame(ImageStack(ims), valid)


@dataclass
class FilterResult:
    """Outcome of :func:`filter_trajectories`.

    Attributes
    ----------
    xyz : ndarray, shape (F, P, 3)
        Filtered trajectories (NaN after truncation / for removed ones).
    bad : ndarray, shape (F, P) bool
        Frames flagged by any filter.
    removed : ndarray, shape (P,) bool
        Trajectories removed entirely.
    truncated : ndarray, shape (P,) bool
        Trajectories cut before their first bad frame (and not removed).
    """

    xyz: np.ndarray
    bad: np.ndarray
    removed: np.ndarray
    truncated: np.ndarray


def filter_trajectories(xyz: np.ndarray, fps: float, *, max_speed: float = 6.0,
                        max_accel: float = 150.0, radius_m: float = 0.05,
                        max_dev: float = 0.3, min_neighbours: int = 3,
                        min_length: int = 5) -> FilterResult:
    """Velocity / acceleration thresholds and local uniformity in space and time.

    Parameters
    ----------
    xyz : ndarray, shape (F, P, 3)
        Trajectories, metres (NaN where unknown).
    fps : float
        Frame rate, frames per second.
    max_speed, max_accel : float
        Thresholds, m/s and m/s².
    radius_m : float
        Neighbourhood radius for the uniformity test, metres.
    max_dev : float
        Largest difference between a point's velocity and the median velocity of its
        neighbours (over frames i-1..i+1), m/s.
    min_length : int
        Trajectories shorter than this after truncation are removed, frames.
    """
    F, P, _ = xyz.shape
    v = _derivative(xyz, fps)
    a = np.full_like(xyz, np.nan)
    a[1:-1] = (xyz[2:] - 2 * xyz[1:-1] + xyz[:-2]) * fps ** 2
    speed = np.linalg.norm(v, axis=2)
    acc = np.linalg.norm(a, axis=2)
    bad = (speed > max_speed) | (acc > max_accel)
    for f in range(F):                      # loop over frames; points are batched
        ok = np.all(np.isfinite(xyz[f]), axis=1) & np.all(np.isfinite(v[f]), axis=1)
        idx = np.flatnonzero(ok)
        if len(idx) < min_neighbours + 1:
            continue
        tree = cKDTree(xyz[f, idx])
        nb = tree.query_ball_point(xyz[f, idx], radius_m, return_sorted=False)
        counts = np.array([len(x) for x in nb])
        kmax = int(counts.max())
        table = np.full((len(idx), kmax), -1)
        for j, x in enumerate(nb):          # ragged neighbour lists -> padded table
            table[j, :len(x)] = x
        # Neighbour velocities over frames f-1, f, f+1, median per component.
        frames = [g for g in (f - 1, f, f + 1) if 0 <= g < F]
        vals = []
        for g in frames:
            vg = v[g, idx]
            nv = np.where((table >= 0)[..., None], vg[np.maximum(table, 0)], np.nan)
            nv[table == np.arange(len(idx))[:, None]] = np.nan     # exclude the point itself
            vals.append(nv)
        vals = np.concatenate(vals, axis=1)
        enough = np.sum(np.isfinite(vals[..., 0]), axis=1) >= min_neighbours * len(frames)
        med = np.full((len(idx), 3), np.nan)
        if enough.any():
            med[enough] = np.nanmedian(vals[enough], axis=1)
        dev = np.linalg.norm(v[f, idx] - med, axis=1)
        bad[f, idx[enough & (dev > max_dev)]] = True
    alive = np.all(np.isfinite(xyz), axis=2)
    bad &= alive
    out = xyz.copy()
    removed = np.zeros(P, bool)
    truncated = np.zeros(P, bool)
    any_bad = bad.any(axis=0)
    first_bad = np.where(any_bad, np.argmax(bad, axis=0), F)
    frame_idx = np.arange(F)[:, None]
    cut = frame_idx >= first_bad[None, :]
    out[cut] = np.nan
    remaining = np.sum(np.all(np.isfinite(out), axis=2), axis=0)
    removed = any_bad & (remaining < min_length)
    truncated = any_bad & ~removed
    out[:, removed] = np.nan
    return FilterResult(xyz=out, bad=bad, removed=removed, truncated=truncated)
