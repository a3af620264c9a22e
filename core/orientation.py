"""Initial orientation of all cameras from wand points alone (no prior guess).

Interior orientation is guessed from the image size (principal point at the centre,
the given pixel aspect, no distortion); the common focal length is searched
(:func:`search_focal`): a wrong focal length distorts the oriented space, so the
intersected bars' lengths scatter, and the focal length whose bars are most nearly
equal wins.  For a
camera pair the essential matrix (five-point RANSAC, OpenCV) gives the relative
orientation; its scale follows from the bar length L (median of the intersected bar
lengths).  Cameras are chained from camera 1 (the datum: its frame is the world)
through the pairs sharing the most wand locations.  The A/B labels of every camera
are made consistent with its parent's, location by location, by the epipolar
(Sampson) distance.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .camera import Camera
from .errors import InputError
from .intersect import triangulate


@dataclass
class InitialOrientation:
    """Cameras (world = camera 1's frame, metres) and relabelled wand points.

    ``uv`` (F, C, 2, 2) has consistent A/B labels across cameras; ``xyz`` (F, 2, 3) the
    intersected targets (NaN where not determined); ``swapped`` (F, C) where labels
    were exchanged; ``order`` the (parent, child) chain.
    """

    cameras: list[Camera]
    uv: np.ndarray
    xyz: np.ndarray
    swapped: np.ndarray
    order: list


def guess_K(size: tuple[int, int], aspect: float = 1.0, f: float | None = None) -> np.ndarray:
    """Intrinsic guess for an image ``(width, height)`` in pixels."""
    w, h = size
    f = float(f) if f is not None else float(max(w, h * aspect))
    return np.array([[f, 0.0, (w - 1) / 2.0], [0.0, f / aspect, (h - 1) / 2.0], [0, 0, 1.0]])


def _normalise(K, uv):
    return np.stack([(uv[..., 0] - K[0, 2]) / K[0, 0], (uv[..., 1] - K[1, 2]) / K[1, 1]], -1)


def _sampson(E, x1, x2):
    """Sampson distances (N,) of normalised correspondences x1 (N, 2), x2 (N, 2)."""
    h1 = np.concatenate([x1, np.ones((len(x1), 1))], 1)
    h2 = np.concatenate([x2, np.ones((len(x2), 1))], 1)
    Ex1 = h1 @ E.T
    Etx2 = h2 @ E
    num = np.sum(h2 * Ex1, axis=1) ** 2
    den = Ex1[:, 0] ** 2 + Ex1[:, 1] ** 2 + Etx2[:, 0] ** 2 + Etx2[:, 1] ** 2
    return num / np.maximum(den, 1e-300)


def relative_pose(K1, K2, uv1, uv2, length_m, thr_px=2.0):
    """Relative orientation of camera 2 w.r.t. camera 1 from wand points.

    Parameters
    ----------
    uv1, uv2 : ndarray, shape (F, 2, 2)
        Both targets in both cameras (finite), labels possibly inconsistent.

    Returns
    -------
    R, t : rotation (3, 3) and translation (3,) metres, camera 1 -> camera 2;
    swap : (F,) bool, where camera 2's labels must be exchanged to match camera 1.
    """
    x1, x2 = _normalise(K1, uv1), _normalise(K2, uv2)
    # both label hypotheses as candidate correspondences; RANSAC sorts them out
    p1 = np.concatenate([x1[:, 0], x1[:, 1], x1[:, 0], x1[:, 1]])
    p2 = np.concatenate([x2[:, 0], x2[:, 1], x2[:, 1], x2[:, 0]])
    f = 0.5 * (K1[0, 0] + K2[0, 0])
    E, mask = cv2.findEssentialMat(
        p1, p2, np.eye(3), method=cv2.RANSAC, prob=0.9999, threshold=thr_px / f, maxIters=5000
    )
    if E is None or E.shape != (3, 3):
        raise InputError("wand points: no relative orientation found for a camera pair")
    same = _sampson(E, x1[:, 0], x2[:, 0]) + _sampson(E, x1[:, 1], x2[:, 1])
    cross = _sampson(E, x1[:, 0], x2[:, 1]) + _sampson(E, x1[:, 1], x2[:, 0])
    swap = cross < same
    x2s = np.where(swap[:, None, None], x2[:, ::-1], x2)
    q1, q2 = x1.reshape(-1, 2), x2s.reshape(-1, 2)
    inl = (np.minimum(same, cross) < 2 * (thr_px / f) ** 2).repeat(2).astype(np.uint8)
    _, R, t, _ = cv2.recoverPose(E, q1, q2, np.eye(3), mask=inl.copy())
    t = t.ravel()
    P1 = np.hstack([np.eye(3), np.zeros((3, 1))])
    P2 = np.hstack([R, t[:, None]])
    X = cv2.triangulatePoints(P1, P2, q1.T, q2.T)
    X = (X[:3] / X[3]).T.reshape(-1, 2, 3)
    d = np.linalg.norm(X[:, 0] - X[:, 1], axis=1)
    good = inl.reshape(-1, 2)[:, 0].astype(bool) & np.isfinite(d) & (d > 0)
    if good.sum() < 5:
        raise InputError("wand points: too few consistent wand locations for a camera pair")
    scale = length_m / np.median(d[good])
    return R, t * scale, swap


def relabel(cameras: list[Camera], uv: np.ndarray) -> np.ndarray:
    """Which images' A/B labels to exchange so that all cameras agree, (F, C) bool.

    Every pair of cameras that sees both targets of a location scores both ways of
    pairing the targets by their epipolar (Sampson) distances, from the cameras'
    relative orientation (distortion ignored); each location takes the labelling of all
    its cameras at once with the smallest total.  A bar imaged along an epipolar line
    of one pair cannot be labelled from that pair, but the other pairs decide.  The
    first camera that sees both targets keeps its labels.  All ``2^(C-1)`` labellings
    are scored, so this is meant for rigs of up to a dozen cameras.
    """
    F, C = uv.shape[:2]
    both = np.all(np.isfinite(uv), axis=(2, 3))
    combos = (np.arange(2 ** (C - 1))[:, None] >> np.arange(C - 1)) & 1
    combos = np.concatenate([np.zeros((len(combos), 1), int), combos], axis=1)  # (B, C)
    cost = np.zeros((F, len(combos)))
    for i in range(C):
        for j in range(i + 1, C):
            sel = both[:, i] & both[:, j]
            if not np.any(sel):
                continue
            R = cameras[j].R @ cameras[i].R.T
            t = cameras[j].t - R @ cameras[i].t
            tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
            E = tx @ R
            x1 = _normalise(cameras[i].K, uv[sel, i])
            x2 = _normalise(cameras[j].K, uv[sel, j])
            same = _sampson(E, x1[:, 0], x2[:, 0]) + _sampson(E, x1[:, 1], x2[:, 1])
            cross = _sampson(E, x1[:, 0], x2[:, 1]) + _sampson(E, x1[:, 1], x2[:, 0])
            differ = combos[:, i] != combos[:, j]  # (B,)
            cost[sel] += np.where(differ[None, :], cross[:, None], same[:, None])
    flip = combos[np.argmin(cost, axis=1)].astype(bool)  # (F, C)
    ref = np.argmax(both, axis=1)
    flip ^= flip[np.arange(F), ref][:, None]
    return flip & both


def initial_orientation(
    uv: np.ndarray,
    sizes: list[tuple[int, int]],
    length_m: float,
    names: list[str] | None = None,
    aspect: float = 1.0,
    f_guess: float | None = None,
) -> InitialOrientation:
    """Orient every camera from wand points, chained from camera 1.

    Parameters
    ----------
    uv : ndarray, shape (F, C, 2, 2)
        Target image points (NaN where not measured).
    sizes : list of (width, height)
    length_m : float
        Bar length, metres.
    aspect : float
        Pixel aspect guess (2 for single-field images).
    """
    uv = np.asarray(uv, dtype=float).copy()
    F, C = uv.shape[:2]
    names = names or [f"cam{i + 1:02d}" for i in range(C)]
    Ks = [guess_K(s, aspect, f_guess) for s in sizes]
    both = np.all(np.isfinite(uv), axis=(2, 3))  # (F, C)
    common = both.T.astype(int) @ both.astype(int)  # (C, C)
    placed = {0: (np.eye(3), np.zeros(3))}
    order = []
    swapped = np.zeros((F, C), dtype=bool)
    while len(placed) < C:
        best = None
        for i in placed:
            for j in range(C):
                if j not in placed and (best is None or common[i, j] > common[best]):
                    best = (i, j)
        i, j = best
        if common[i, j] < 8:
            raise InputError(
                f"wand: camera {names[j]} shares fewer than 8 wand locations "
                "with the oriented cameras"
            )
        sel = both[:, i] & both[:, j]
        R, t, swap = relative_pose(Ks[i], Ks[j], uv[sel, i], uv[sel, j], length_m)
        rows = np.flatnonzero(sel)[swap]
        uv[rows, j] = uv[rows, j, ::-1]
        swapped[rows, j] = True
        Ri, ti = placed[i]
        placed[j] = (R @ Ri, R @ ti + t)
        order.append((i, j))
    cams = [Camera(names[c], sizes[c], Ks[c], np.zeros(5), *placed[c]) for c in range(C)]
    flip = relabel(cams, uv)
    uv[flip] = uv[flip][:, ::-1]
    swapped ^= flip
    pts = uv.transpose(0, 2, 1, 3).reshape(F * 2, C, 2)
    res = triangulate(cams, pts, sigma_px=1.0)
    xyz = res.xyz.reshape(F, 2, 3)
    return InitialOrientation(cameras=cams, uv=uv, xyz=xyz, swapped=swapped, order=order)


def bar_scatter(init: InitialOrientation) -> float:
    """Relative scatter of the intersected bar lengths: MAD / median (NaN if none)."""
    d = np.linalg.norm(init.xyz[:, 0] - init.xyz[:, 1], axis=1)
    d = d[np.isfinite(d)]
    if d.size < 5:
        return np.nan
    med = np.median(d)
    return float(np.median(np.abs(d - med)) / med)


def search_focal(
    uv: np.ndarray,
    sizes: list[tuple[int, int]],
    length_m: float,
    names: list[str] | None = None,
    aspect: float = 1.0,
    factors: tuple[float, ...] = tuple(2.0 ** (k / 3.0) for k in range(-3, 7)),
) -> tuple[float, InitialOrientation]:
    """Common focal length (px) whose initial orientation makes the bars most equal.

    Candidates ``factor · max(width, height · aspect)`` of the first camera; the best
    one is refined by a parabola through its neighbours on a log scale.  The median
    and MAD make the criterion insensitive to bad blobs.  Returns the focal length and
    the initial orientation made with it.
    """
    w, h = sizes[0]
    base = float(max(w, h * aspect))
    fs = base * np.asarray(factors, dtype=float)
    score = np.full(fs.size, np.inf)
    for i, f in enumerate(fs):  # a few candidates, each a full orientation
        try:
            score[i] = bar_scatter(initial_orientation(uv, sizes, length_m, names, aspect, f))
        except InputError:
            continue
    score = np.where(np.isfinite(score), score, np.inf)
    if not np.isfinite(score).any():
        return base, initial_orientation(uv, sizes, length_m, names, aspect, base)
    i = int(np.argmin(score))
    f = fs[i]
    if 0 < i < fs.size - 1 and np.all(np.isfinite(score[i - 1 : i + 2])):
        y0, y1, y2 = score[i - 1 : i + 2]
        den = y0 - 2 * y1 + y2
        if den > 0:
            step = np.log(fs[i + 1] / fs[i])
            f = float(np.exp(np.log(fs[i]) + 0.5 * step * (y0 - y2) / den))
    init = initial_orientation(uv, sizes, length_m, names, aspect, f)
    if not bar_scatter(init) <= score[i]:
        init, f = initial_orientation(uv, sizes, length_m, names, aspect, fs[i]), fs[i]
    return float(f), init
