"""Z-buffered ray–ellipsoid rendering of a body: numpy, or compiled (numba).

:func:`core.model_render.render_parts` renders the body's ellipsoids into a camera:
for every pixel of an ellipsoid's projected bounding box the pixel's viewing ray
``o + s d`` (``o`` the projection centre, ``d`` the unit direction, world metres) is
intersected in closed form with the ellipsoid mapped to the unit sphere,
``q(s) = A (o − c) + s A d`` with ``A = Rᵀ / r`` (``R`` the ellipsoid's axes as
columns, ``r`` its semi-axes): ``a s² + b s + c = 0`` with ``a = |A d|²``,
``b = 2 (A d)·(A (o − c))``, ``c = |A (o − c)|² − 1``.  A z-buffer keeps the nearest
surface (``s`` is the depth along the ray, metres, the rays being unit vectors).

:func:`render_numpy` is the reference: one ellipsoid at a time with (box, 3)
temporaries.  :func:`render_compiled` loops over the pixels of each box instead and
gives the same four arrays **bit for bit** on every machine.  Both write each product
and sum of three out as elementwise operations, left to right and each rounded
(``x0 y0 + x1 y1`` first, then ``+ x2 y2``; :func:`sphere_offsets`, ``dl``, ``a``,
``b`` and the buried-surface test), never through numpy's ``@`` or ``einsum``: those
pick BLAS and SIMD kernels at run time whose summation order depends on the CPU and
even on the arrays' alignment (AVX-512's ``dgemv`` sums a box row's first pixel in
another order than the rest), so no compiled loop could follow them everywhere.
Elementwise ufuncs round every operation as IEEE does, and the compiled loops, built
without fastmath, fuse nothing.

Optional at run time like :mod:`core.ellipse_kernel`: without numba (the Blender add-on
does not bundle it), with ``SOMACAP_NO_NUMBA=1``, or after a failed first compile, the
numpy path runs.

Frames: world Z up, metres; cameras as in :mod:`core.camera` (pixel ``(u, v)`` at row
``v``, column ``u``; distortion honoured through each pixel's undistorted viewing ray).
"""

from __future__ import annotations

import math

import numpy as np

from .camera import Camera
from .field_kernel import enabled as numba_enabled
from .field_kernel import run
from .lsm_kernel_jit import numba

SHRINK = 0.995  # a surface point inside another ellipsoid shrunk by this is buried
MAX_BIT_PARTS = 64  # parts whose covered pixels are tracked (one bit each)

_CHECK: dict = {"agrees": None}


def _jit():
    """``numba.njit`` as :func:`core.lsm_kernel_jit.jit` (cached, no fastmath), with
    numpy's error model: ``x / 0.0`` gives ±inf or nan as in numpy instead of raising
    (a zero ray direction); identity without numba."""

    def deco(fn):
        if numba is None:
            return fn
        try:
            return numba.njit(cache=True, nogil=True, error_model="numpy")(fn)
        except RuntimeError:  # no cache locator: compile per process
            return numba.njit(cache=False, nogil=True, error_model="numpy")(fn)

    return deco


def ray_grid(camera: Camera, step: int = 1) -> np.ndarray:
    """Unit world viewing directions of every ``step``-th pixel, shape (H, W, 3)."""
    w, h = camera.size
    vv, uu = np.mgrid[0:h:step, 0:w:step]
    uv = np.stack([uu, vv], axis=-1).astype(float)
    _, d = camera.rays(uv)
    return d  # (h, w, 3) unit world directions


def _inputs(centers, axes, radii, part, n_parts):
    centers = np.asarray(centers, float)
    axes = np.asarray(axes, float)
    radii = np.asarray(radii, float)
    part = np.asarray(part, int)
    n_parts = int(part.max()) + 1 if n_parts is None else n_parts
    return centers, axes, radii, part, n_parts


def _corners_uv(camera: Camera, centers, axes, radii):
    """Projections (E, 8, 2) px and camera depths (E, 8) m of each ellipsoid's box corners."""
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    pts = centers[:, None, :] + np.einsum("eij,ekj->eki", axes, corners[None] * radii[:, None, :])
    uv = camera.project(pts.reshape(-1, 3)).reshape(len(centers), 8, 2)
    cam_z = camera.to_camera(pts.reshape(-1, 3))[:, 2].reshape(len(centers), 8)
    return uv, cam_z


def render_numpy(
    camera: Camera,
    centers: np.ndarray,
    axes: np.ndarray,
    radii: np.ndarray,
    part: np.ndarray,
    n_parts: int | None = None,
    rays: np.ndarray | None = None,
    outer_only: bool = False,
    buried_by: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The rendering of :func:`core.model_render.render_parts` with numpy: the reference.

    Parameters are those of :func:`core.model_render.render_parts` (centres (E, 3) and
    semi-axes (E, 3) in metres, axes (E, 3, 3) with the principal axes as columns in
    world, parts (E,), rays (H, W, 3) unit world directions).

    Returns
    -------
    part_id : ndarray, shape (H, W), int
        Front-most part at each pixel, -1 for background.
    depth : ndarray, shape (H, W), float
        Distance along the viewing ray to the front-most surface, metres (inf: none).
    full_area : ndarray, shape (P,), int
        Pixels each part covers ignoring occlusion (all zero when P > 64).
    visible_area : ndarray, shape (P,), int
        Pixels where each part is the front-most surface.
    """
    centers, axes, radii, part, n_parts = _inputs(centers, axes, radii, part, n_parts)
    w, h = camera.size
    d_all = ray_grid(camera) if rays is None else rays
    origin = camera.center
    depth = np.full((h, w), np.inf)
    part_id = np.full((h, w), -1, int)
    full_area = np.zeros(n_parts, int)
    covered = np.zeros((n_parts, h, w), bool) if n_parts <= MAX_BIT_PARTS else None

    # projected bounding boxes from the 8 corners of each ellipsoid's box
    A_all = np.transpose(axes, (0, 2, 1)) / radii[:, :, None]  # world -> unit sphere
    oc_all, c_all = sphere_offsets(A_all, origin, centers)
    reach = radii.max(axis=1)
    near = np.linalg.norm(centers[:, None] - centers[None], axis=2) < reach[:, None] + reach[None]
    uv, cam_z = _corners_uv(camera, centers, axes, radii)
    for e in range(len(centers)):
        if np.any(cam_z[e] <= 1e-6) or not np.all(np.isfinite(uv[e])):
            # behind or straddling the camera: test the whole image (rare)
            u0, v0, u1, v1 = 0, 0, w - 1, h - 1
        else:
            u0 = max(int(np.floor(uv[e, :, 0].min())) - 1, 0)
            v0 = max(int(np.floor(uv[e, :, 1].min())) - 1, 0)
            u1 = min(int(np.ceil(uv[e, :, 0].max())) + 1, w - 1)
            v1 = min(int(np.ceil(uv[e, :, 1].max())) + 1, h - 1)
        if u0 > u1 or v0 > v1:
            continue
        d = d_all[v0 : v1 + 1, u0 : u1 + 1]  # (bh, bw, 3)
        # ray o + s d in the ellipsoid's unit-sphere frame: q(s) = A (o - c) + s A d
        A, oc, c = A_all[e], oc_all[e], c_all[e]  # world -> unit sphere
        dl0, dl1, dl2 = (_dot3(d[..., 0], d[..., 1], d[..., 2], A[i]) for i in range(3))
        a = _dot3(dl0, dl1, dl2, (dl0, dl1, dl2))
        b = _dot3(2.0 * dl0, 2.0 * dl1, 2.0 * dl2, oc)
        disc = b * b - 4.0 * a * c
        hit = disc >= 0
        sq = np.sqrt(np.where(hit, disc, 0.0))
        s_near = (-b - sq) / (2.0 * a)
        s_far = (-b + sq) / (2.0 * a)
        s = np.where(s_near > 0, s_near, s_far)
        hit &= s > 0
        if not hit.any():
            continue
        p = part[e]
        full_area_box = hit
        if outer_only:
            others = np.flatnonzero(near[e])
            others = others[others != e]
            if buried_by is not None:
                others = others[np.asarray(buried_by, bool)[part[e], part[others]]]
            if len(others):
                full_area_box = hit & (
                    _outer(origin, d, s_near, others, A_all, centers)
                    | _outer(origin, d, s_far, others, A_all, centers)
                )
        if covered is not None:
            covered[p, v0 : v1 + 1, u0 : u1 + 1] |= full_area_box
        sub_depth = depth[v0 : v1 + 1, u0 : u1 + 1]
        closer = hit & (s < sub_depth)
        sub_depth[closer] = s[closer]
        part_id[v0 : v1 + 1, u0 : u1 + 1][closer] = p
    if covered is not None:
        full_area = covered.reshape(n_parts, -1).sum(axis=1)
    visible_area = np.bincount(part_id[part_id >= 0], minlength=n_parts)[:n_parts]
    return part_id, depth, full_area, visible_area


def _dot3(x0, x1, x2, y):
    """``(x0 y[0] + x1 y[1]) + x2 y[2]``, elementwise and each operation rounded (the
    compiled loops' order)."""
    return (x0 * y[0] + x1 * y[1]) + x2 * y[2]


def sphere_offsets(A_all: np.ndarray, origin: np.ndarray, centers: np.ndarray):
    """The projection centre in each ellipsoid's unit-sphere frame.

    Parameters
    ----------
    A_all : ndarray, shape (E, 3, 3)
        World to unit sphere, ``Rᵀ / r`` per ellipsoid.
    origin : ndarray, shape (3,)
        Projection centre, world metres.
    centers : ndarray, shape (E, 3)
        Ellipsoid centres, world metres.

    Returns
    -------
    oc : ndarray, shape (E, 3)
        ``A (o − c)``, unitless.
    c : ndarray, shape (E,)
        ``|A (o − c)|² − 1``: the constant term of the ray's quadratic.
    """
    y = origin - centers
    oc = np.stack([_dot3(y[:, 0], y[:, 1], y[:, 2], A_all[:, i].T) for i in range(3)], axis=1)
    return oc, _dot3(oc[:, 0], oc[:, 1], oc[:, 2], oc.T) - 1.0


def _outer(origin, d, s, others, A_all, centers, shrink: float = SHRINK) -> np.ndarray:
    """Whether the points ``origin + s d`` (h, w) lie inside none of ``others``."""
    x = origin + np.where(np.isfinite(s), s, 0.0)[..., None] * d  # (h, w, 3)
    y = x[:, :, None, :] - centers[others]  # (h, w, O, 3)
    Ao = A_all[others]  # (O, 3, 3)
    q = [_dot3(y[..., 0], y[..., 1], y[..., 2], Ao[:, i].T) for i in range(3)]
    return ~np.any(_dot3(*q, q) < shrink**2, axis=2) & (s > 0)


def render_compiled(
    camera: Camera,
    centers: np.ndarray,
    axes: np.ndarray,
    radii: np.ndarray,
    part: np.ndarray,
    n_parts: int | None = None,
    rays: np.ndarray | None = None,
    outer_only: bool = False,
    buried_by: np.ndarray | None = None,
    check: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """:func:`render_numpy` with compiled loops over each box's pixels: the same arrays.

    Parameters are those of :func:`render_numpy`; ``check=False`` skips the one-time
    comparison with the numpy path (:func:`agrees`), for tests.

    Returns
    -------
    (part_id, depth, full_area, visible_area) as :func:`render_numpy`, or None where
    the compiled path cannot run: numba missing or switched off, its arithmetic not
    numpy's on this machine (:func:`agrees`), ``rays`` not a C-contiguous float64
    (H, W, 3) array (numpy's products then take other code paths), or a part index
    outside ``[0, n_parts)``.
    """
    if not numba_enabled() or (check and not agrees()):
        return None
    centers, axes, radii, part, n_parts = _inputs(centers, axes, radii, part, n_parts)
    w, h = camera.size
    d_all = ray_grid(camera) if rays is None else rays
    if (
        not isinstance(d_all, np.ndarray)
        or d_all.dtype != np.float64
        or d_all.shape != (h, w, 3)
        or not d_all.flags.c_contiguous
    ):
        return None
    E = len(centers)
    if E and (part.min() < 0 or part.max() >= n_parts):
        return None
    origin = camera.center
    depth = np.full((h, w), np.inf)
    part_id = np.full((h, w), -1, int)
    full_area = np.zeros(n_parts, int)
    visible_area = np.zeros(n_parts, int)
    if E == 0:
        return part_id, depth, full_area, visible_area
    bits = np.zeros((h, w) if n_parts <= MAX_BIT_PARTS else (0, 0), np.uint64)

    A_all = np.transpose(axes, (0, 2, 1)) / radii[:, :, None]  # world -> unit sphere
    uv, cam_z = _corners_uv(camera, centers, axes, radii)
    box = _boxes(uv, cam_z, w, h)
    oc, c = sphere_offsets(A_all, origin, centers)
    if outer_only:
        reach = radii.max(axis=1)
        dist = np.linalg.norm(centers[:, None] - centers[None], axis=2)
        pairs = (dist < reach[:, None] + reach[None]) & ~np.eye(E, dtype=bool)
        if buried_by is not None:
            pairs &= np.asarray(buried_by, bool)[part[:, None], part[None, :]]
    else:
        pairs = np.zeros((E, E), bool)
    start = np.concatenate([[0], np.cumsum(pairs.sum(axis=1))]).astype(np.int64)
    others = np.nonzero(pairs)[1].astype(np.int64)  # row-major: each row's in order
    ok = run(
        _render_loops,
        d_all,
        np.ascontiguousarray(origin, dtype=float),
        np.ascontiguousarray(A_all),
        oc,
        c,
        box,
        np.ascontiguousarray(part, dtype=np.int64),
        start,
        others,
        np.ascontiguousarray(centers),
        float(SHRINK**2),
        depth,
        part_id,
        bits,
        full_area,
        visible_area,
    )
    return (part_id, depth, full_area, visible_area) if ok else None


def _boxes(uv: np.ndarray, cam_z: np.ndarray, w: int, h: int) -> np.ndarray:
    """Pixel boxes (E, 4) ``u0, v0, u1, v1`` (inclusive; empty when u0 > u1 or v0 > v1)
    of ellipsoids whose box corners project to ``uv`` (E, 8, 2) at depths ``cam_z``
    (E, 8): the corners' extent plus one pixel, clipped to the image; the whole image
    for one behind or straddling the camera.  The reference's per-ellipsoid boxes."""
    whole = np.any(cam_z <= 1e-6, axis=1) | ~np.all(np.isfinite(uv), axis=(1, 2))
    uvf = np.where(np.isfinite(uv), uv, 0.0)
    size = np.array([w, h], float)
    # clip in floats (exact integers below 2**52; huge values clip to empty boxes)
    lo = np.clip(np.floor(uvf.min(axis=1)) - 1, 0, size)
    hi = np.clip(np.ceil(uvf.max(axis=1)) + 1, -1, size - 1)
    box = np.concatenate([lo, hi], axis=1).astype(np.int64)
    box[whole] = (0, 0, w - 1, h - 1)
    return box


def agrees() -> bool:
    """Whether the compiled path gives numpy's arrays bit for bit on this machine.

    Rendered once per process (then remembered): a small test body of overlapping,
    rotated ellipsoids of four parts, one straddling the image border and one the
    camera's plane, one behind the camera, plain and with ``outer_only``, in a 64 × 48
    camera and in a one-pixel-wide one.  False (and
    the numpy path from then on) when numba is missing, fails to compile, or any array
    differs.
    """
    if _CHECK["agrees"] is None:
        if not numba_enabled():
            return False
        cameras, body = _test_body()
        ok = True
        for camera in cameras:
            for outer_only in (False, True):
                ref = render_numpy(camera, *body, outer_only=outer_only)
                got = render_compiled(camera, *body, outer_only=outer_only, check=False)
                ok = ok and got is not None
                ok = ok and all(np.array_equal(x, y) for x, y in zip(got, ref, strict=True))
        _CHECK["agrees"] = bool(ok)
    return bool(_CHECK["agrees"]) and numba_enabled()


def _test_body():
    """Two cameras looking along world +Y from y = −3 m (64 × 48 px, with distortion;
    1 × 48 px through the middle) and a body (centres, axes, radii, parts, 4 parts) for
    :func:`agrees`."""
    R = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
    t = -R @ np.array([0.0, -3.0, 0.0])
    K = np.array([[60.0, 0, 31.5], [0, 60.0, 23.5], [0, 0, 1]])
    dist = np.array([0.05, -0.01, 0.001, 0.0, 0.0])
    column = K.copy()
    column[0, 2] = 0.0
    cameras = (
        Camera("check", (64, 48), K, dist, R, t),
        Camera("check1", (1, 48), column, np.zeros(5), R, t),
    )
    rng = np.random.default_rng(0)
    n = 14
    centers = rng.uniform([-1.0, -0.4, -0.7], [1.0, 0.4, 0.7], (n, 3))
    centers[0] = (1.7, 0.0, 0.2)  # across the right border
    centers[1] = (0.0, -3.5, 0.0)  # behind the camera
    centers[2] = (0.1, -2.2, -0.1)  # across the camera's plane, long along the view
    axes = np.linalg.qr(rng.normal(size=(n, 3, 3)))[0]
    axes[2] = np.eye(3)
    radii = rng.uniform(0.08, 0.4, (n, 3))
    radii[2] = (0.1, 1.2, 0.1)
    part = rng.integers(0, 4, n)
    return cameras, (centers, axes, radii, part, 4)


@_jit()
def _norm2_in(x0, x1, x2, A, c):  # pragma: no cover - compiled
    """``|A (x − c)|²`` of a world point ``x`` for one ellipsoid (``A`` (3, 3) world to
    unit sphere, ``c`` (3,) its centre) with the sums of :func:`_outer`."""
    y0 = x0 - c[0]
    y1 = x1 - c[1]
    y2 = x2 - c[2]
    q0 = (y0 * A[0, 0] + y1 * A[0, 1]) + y2 * A[0, 2]
    q1 = (y0 * A[1, 0] + y1 * A[1, 1]) + y2 * A[1, 2]
    q2 = (y0 * A[2, 0] + y1 * A[2, 1]) + y2 * A[2, 2]
    return (q0 * q0 + q1 * q1) + q2 * q2


@_jit()
def _outside(x0, x1, x2, A_all, centers, others, j0, j1, shrink2):  # pragma: no cover
    """Whether the world point ``x`` lies inside none of the ellipsoids ``others[j0:j1]``
    shrunk by ``sqrt(shrink2)``."""
    for j in range(j0, j1):
        o = others[j]
        if _norm2_in(x0, x1, x2, A_all[o], centers[o]) < shrink2:
            return False
    return True


@_jit()
def _on_outer_surface(
    s, origin, d0, d1, d2, A_all, centers, others, j0, j1, shrink2
):  # pragma: no cover
    """:func:`_outer` at one pixel: ``s > 0`` and ``origin + s d`` inside none of the
    ellipsoids ``others[j0:j1]``."""
    if not s > 0:
        return False
    sf = s if math.isfinite(s) else 0.0
    return _outside(
        origin[0] + sf * d0,
        origin[1] + sf * d1,
        origin[2] + sf * d2,
        A_all,
        centers,
        others,
        j0,
        j1,
        shrink2,
    )


@_jit()
def _render_loops(  # pragma: no cover - compiled
    d_all,
    origin,
    A_all,
    oc,
    c,
    box,
    part,
    start,
    others,
    centers,
    shrink2,
    depth,
    part_id,
    bits,
    full_area,
    visible_area,
):
    """:func:`render_numpy`'s loop over ellipsoids, with loops over their boxes' pixels.

    Fills ``depth`` (H, W), ``part_id`` (H, W), ``visible_area`` (P,) and, when ``bits``
    is (H, W) (one bit per part, P ≤ 64), ``full_area`` (P,).  ``others[start[e]:
    start[e + 1]]``: the ellipsoids that bury ``e``'s surface (``outer_only``; none
    without it).
    """
    track = bits.shape[0] > 0
    for e in range(A_all.shape[0]):
        u0, v0, u1, v1 = box[e, 0], box[e, 1], box[e, 2], box[e, 3]
        if u0 > u1 or v0 > v1:
            continue
        p = part[e]
        bit = np.uint64(1) << np.uint64(p)
        j0, j1 = start[e], start[e + 1]
        A = A_all[e]
        oc0, oc1, oc2 = oc[e, 0], oc[e, 1], oc[e, 2]
        ce = c[e]
        for v in range(v0, v1 + 1):
            for u in range(u0, u1 + 1):
                d0, d1, d2 = d_all[v, u, 0], d_all[v, u, 1], d_all[v, u, 2]
                dl0 = (d0 * A[0, 0] + d1 * A[0, 1]) + d2 * A[0, 2]
                dl1 = (d0 * A[1, 0] + d1 * A[1, 1]) + d2 * A[1, 2]
                dl2 = (d0 * A[2, 0] + d1 * A[2, 1]) + d2 * A[2, 2]
                a = (dl0 * dl0 + dl1 * dl1) + dl2 * dl2
                b = (2.0 * dl0 * oc0 + 2.0 * dl1 * oc1) + 2.0 * dl2 * oc2
                disc = b * b - 4.0 * a * ce
                if not disc >= 0:
                    continue
                sq = math.sqrt(disc)
                s_near = (-b - sq) / (2.0 * a)
                s_far = (-b + sq) / (2.0 * a)
                s = s_near if s_near > 0 else s_far
                if not s > 0:
                    continue
                if track and not bits[v, u] & bit:
                    if j1 == j0 or (
                        _on_outer_surface(
                            s_near, origin, d0, d1, d2, A_all, centers, others, j0, j1, shrink2
                        )
                        or _on_outer_surface(
                            s_far, origin, d0, d1, d2, A_all, centers, others, j0, j1, shrink2
                        )
                    ):
                        bits[v, u] |= bit
                        full_area[p] += 1
                if s < depth[v, u]:
                    depth[v, u] = s
                    q = part_id[v, u]
                    if q >= 0:
                        visible_area[q] -= 1
                    part_id[v, u] = p
                    visible_area[p] += 1
