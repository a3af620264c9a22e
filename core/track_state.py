"""Per-point state that :func:`core.tracking.track` carries from one frame step to the next.

:class:`TrackerState` holds, for P points in C cameras, the point filters, each camera's
last measurement (the template of the next temporal match), the coasting / dormant
counters, the key templates, the per-frame histories that become
:class:`core.tracking.Tracks`, and the ring of frames still needed as templates.  The
steps that change it live in :mod:`core.track_step`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera import Camera
from .lsm import ImageStack
from .surface import Surface
from .track_anchor import KeyTemplates
from .track_filter import COV_FLOOR, PointFilter


@dataclass
class Frame:
    """The images of one frame.

    Attributes
    ----------
    stack : ImageStack
        C grey images (a black image where a camera has none).
    valid : ndarray, shape (C,), bool
        The camera has an image in this frame.
    """

    stack: ImageStack
    valid: np.ndarray


def load_frame(images, cameras: list[Camera], i: int) -> Frame:
    """Frame ``i`` from ``images`` (list of C grey images or None, in camera order)."""
    valid = np.array([im is not None for im in images])
    if len(images) != len(cameras):
        raise ValueError(f"frame {i}: {len(images)} images for {len(cameras)} cameras")
    if not valid.any():
        raise ValueError(f"frame {i}: no camera has an image")
    shape = next(im for im in images if im is not None).shape
    ims = [im if im is not None else np.zeros(shape, np.uint8) for im in images]
    return Frame(ImageStack(ims), valid)


def _sigma(cov: np.ndarray) -> np.ndarray:
    """(P, 3) standard deviations from (P, 3, 3) covariances."""
    return np.sqrt(np.abs(np.diagonal(cov, axis1=1, axis2=2)))


def _pad(a: np.ndarray, k: int) -> np.ndarray:
    return np.concatenate([a, np.full((k,) + a.shape[1:], np.nan)])


@dataclass
class TrackerState:
    """What the tracker knows of P points in C cameras after a frame.

    Attributes
    ----------
    cameras : list of Camera, length C
    ref : int
        Reference camera of the surface (spatial matches start from it).
    viewpoint : ndarray, shape (3,)
        Mean camera centre, world metres (depth of the depth test).
    kf : PointFilter
        Constant-velocity filters of the P points, world metres and m/frame.
    last_f : ndarray, shape (P, C), int
        Last frame in which each camera measured the point (-1: never).
    last_uv : ndarray, shape (P, C, 2)
        The image point there, pixels.
    prev_uv : ndarray, shape (P, C, 2)
        The image point in the frame before ``last_f`` where measured there, else NaN.
    coast : ndarray, shape (P,), int
        Frames since the point was last measured.
    dead : ndarray, shape (P,), bool
        Not tracked (lost, or dormant).
    gone : ndarray, shape (P,), bool
        Dropped for good.
    keys : KeyTemplates
        Key templates of the (point, camera) pairs (:mod:`core.track_anchor`).
    aff_sp : ndarray, shape (P, C, 2, 2)
        Spatial affine from the reference camera into each camera.
    start : ndarray, shape (P,), int
        First frame of each trajectory.
    uv_hist, xyz_hist, sig_hist : list of ndarray
        Per frame: measured image points (P, C, 2) px, positions (P, 3) m and their
        standard deviations (P, 3) m; NaN where not measured.
    rate_hist : list of ndarray, shape (P, 3)
        Per frame: filtered rates of the measured points, m/frame.
    pred_hist : list of ndarray, shape (P, 3)
        Per frame: predictions of coasting / dormant points (the bridges of their gaps).
    ring : dict of int to Frame
        The frames still needed: the last ``max_coast + 2`` and the key frames.
    """

    cameras: list
    ref: int
    viewpoint: np.ndarray
    kf: PointFilter
    last_f: np.ndarray
    last_uv: np.ndarray
    prev_uv: np.ndarray
    coast: np.ndarray
    dead: np.ndarray
    gone: np.ndarray
    keys: KeyTemplates
    aff_sp: np.ndarray
    start: np.ndarray
    uv_hist: list
    xyz_hist: list
    sig_hist: list
    rate_hist: list
    pred_hist: list
    ring: dict

    @classmethod
    def begin(
        cls, surface: Surface, cameras: list[Camera], frame0: Frame, accel_sigma: float
    ) -> TrackerState:
        """The state at frame 0: the surface's points, measured there."""
        p0 = len(surface)
        return cls(
            cameras=cameras,
            ref=surface.ref,
            viewpoint=np.mean([cam.center for cam in cameras], axis=0),
            kf=PointFilter.start(surface.xyz, surface.cov + COV_FLOOR, accel_sigma=accel_sigma),
            last_f=np.where(np.all(np.isfinite(surface.uv), axis=2), 0, -1),
            last_uv=surface.uv.copy(),
            prev_uv=np.full_like(surface.uv, np.nan),
            coast=np.zeros(p0, int),
            dead=np.zeros(p0, bool),
            gone=np.zeros(p0, bool),
            keys=KeyTemplates.start(surface.uv, 0),
            aff_sp=surface.affine.copy(),
            start=np.zeros(p0, int),
            uv_hist=[surface.uv.copy()],
            xyz_hist=[surface.xyz.copy()],
            sig_hist=[_sigma(surface.cov)],
            rate_hist=[np.zeros((p0, 3))],
            pred_hist=[np.full((p0, 3), np.nan)],
            ring={0: frame0},
        )

    def __len__(self) -> int:
        return len(self.kf)

    def add_frame(self, frame: Frame, i: int, max_coast: int, anchor: bool) -> None:
        """Put frame ``i`` in the ring; release the frames no template needs any more.

        Frames older than ``i - 1 - max_coast`` stay only as key frames (``anchor``),
        without their cached upsampled mosaic.
        """
        self.ring[i] = frame
        needed = self.keys.frames() if anchor else set()
        for f in [f for f in self.ring if f < i - 1 - max_coast]:
            if f not in needed:
                del self.ring[f]
            elif f == i - max_coast - 2:  # drop the cached upsampled mosaic
                self.ring[f] = Frame(ImageStack(self.ring[f].stack.images), self.ring[f].valid)

    def key_stacks(self) -> dict:
        """Image stacks of the key frames, by frame index."""
        return {f: self.ring[f].stack for f in self.keys.frames()}

    def record(
        self,
        i: int,
        uv: np.ndarray,
        xyz: np.ndarray,
        cov: np.ndarray,
        chosen: np.ndarray,
        key_ok: np.ndarray,
        key_aff: np.ndarray,
        pred: np.ndarray,
    ) -> None:
        """Close the step into frame ``i``: templates, key templates and histories.

        Parameters
        ----------
        uv : ndarray, shape (P, C, 2)
            Image points measured at frame ``i``, pixels (NaN where not).
        xyz, cov : ndarray, shapes (P, 3) and (P, 3, 3)
            Their forward intersections, metres and m² (NaN where not measured).
        chosen : ndarray, shape (P,), bool
            Measured at frame ``i``.
        key_ok, key_aff : ndarray, shapes (P, C) bool and (P, C, 2, 2)
            The key match held, and its affine from the key template into frame ``i``;
            elsewhere a measured camera's key is reset to frame ``i``.
        pred : ndarray, shape (P, 3)
            Predictions of coasting / dormant points at frame ``i``, metres.
        """
        self.keys.f[self.gone] = -1  # their key frames may be released
        got = np.all(np.isfinite(uv), axis=2)
        self.keys.affine[got & key_ok] = key_aff[got & key_ok]
        gp, gc = np.nonzero(got & ~key_ok)
        self.keys.reset(gp, gc, uv[gp, gc], i)
        self.prev_uv = np.where(
            (got & (self.last_f == i - 1))[..., None],
            self.last_uv,
            np.where(got[..., None], np.nan, self.prev_uv),
        )
        self.last_uv = np.where(got[..., None], uv, self.last_uv)
        self.last_f = np.where(got, i, self.last_f)
        self.uv_hist.append(uv)
        self.xyz_hist.append(xyz)
        self.sig_hist.append(_sigma(cov))
        self.rate_hist.append(np.where(chosen[:, None], self.kf.x[:, 3:], np.nan))
        self.pred_hist.append(pred)

    def append(self, new: Surface, rate0: np.ndarray, rate_sigma: np.ndarray, i: int) -> None:
        """Add the K points of ``new``, measured at frame ``i`` (the last recorded).

        ``rate0`` (K, 3) m/frame and ``rate_sigma`` start their filters.
        """
        k = len(new)
        for name in ("uv_hist", "xyz_hist", "sig_hist", "rate_hist", "pred_hist"):
            setattr(self, name, [_pad(a, k) for a in getattr(self, name)])
        self.uv_hist[-1][-k:] = new.uv
        self.xyz_hist[-1][-k:] = new.xyz
        self.sig_hist[-1][-k:] = _sigma(new.cov)
        self.rate_hist[-1][-k:] = rate0
        self.kf.append(PointFilter.start(new.xyz, new.cov + COV_FLOOR, rate0, rate_sigma))
        self.start = np.concatenate([self.start, np.full(k, i)])
        self.aff_sp = np.concatenate([self.aff_sp, new.affine])
        self.keys.append(KeyTemplates.start(new.uv, i))
        seen = np.all(np.isfinite(new.uv), axis=2)
        self.last_f = np.concatenate([self.last_f, np.where(seen, i, -1)])
        self.last_uv = np.concatenate([self.last_uv, new.uv])
        self.prev_uv = np.concatenate([self.prev_uv, np.full_like(new.uv, np.nan)])
        self.coast = np.concatenate([self.coast, np.zeros(k, int)])
        self.dead = np.concatenate([self.dead, np.zeros(k, bool)])
        self.gone = np.concatenate([self.gone, np.zeros(k, bool)])
