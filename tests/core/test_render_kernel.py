"""Z-buffered ellipsoid rendering (:mod:`core.render_kernel`): compiled against numpy.

The compiled path must give the numpy path's arrays bit for bit (the fit downstream
is sensitive to the last bit): random bodies in the walk's real cameras, with and
without ``outer_only`` / ``buried_by`` and precomputed rays, over 64 parts, in
one-pixel-wide and one-pixel-high images.
"""

from pathlib import Path

import numpy as np
import pytest

from core import field_kernel, render_kernel
from core.calibration_io import read_calibration
from core.camera import Camera
from core.model_render import camera_rays, neighbour_parts, render_parts

CALIBRATION = Path(__file__).parents[2] / "sample_scenes" / "walk_line3" / "calibration.toml"

#: the compiled path is on where numba is and its first render agrees with numpy's
#: (:func:`core.render_kernel.agrees`); elsewhere ``render_parts`` runs numpy (tested
#: below regardless)
needs_compiled = pytest.mark.skipif(
    not (field_kernel.enabled() and render_kernel.agrees()),
    reason="numba missing, or numpy sums in another order here: the compiled path is off",
)


def _cameras():
    """The walk's three cameras, and the first with lens distortion."""
    cams = read_calibration(CALIBRATION)
    c = cams[0]
    return cams + [Camera("dist", c.size, c.K, np.array([-0.2, 0.1, 1e-3, -2e-3, 0.0]), c.R, c.t)]


def _body(camera, seed, n=40, n_parts=8):
    """Random ellipsoids (centres, axes, radii, parts) in front of ``camera``, ~7 m
    away, some overlapping, some across the image border, one behind the camera, one
    across the camera's plane and one outside the image; part ``n_parts - 1`` has none."""
    rng = np.random.default_rng(seed)
    w, h = camera.size
    uv = rng.uniform([-40, -40], [w + 40, h + 40], (n, 2))
    _, d = camera.rays(uv)
    fwd = camera.R[2]
    depth = 7.0 + rng.uniform(-0.6, 0.6, n)
    centers = camera.center + d * (depth / (d @ fwd))[:, None]
    axes = np.linalg.qr(rng.normal(size=(n, 3, 3)))[0]
    radii = rng.uniform(0.03, 0.25, (n, 3))
    part = rng.integers(0, n_parts - 1, n)
    centers[0] = camera.center - 0.5 * fwd  # behind the camera
    centers[1] = camera.center + 0.9 * fwd + 0.25 * camera.R[0]  # across its plane
    axes[1] = camera.R.T  # long along the viewing direction, seen at the right
    radii[1] = (0.03, 0.03, 1.0)
    centers[2] = camera.center + 7.0 * fwd + 3.0 * camera.R[0]  # outside the image
    return centers, axes, radii, part


def _buried_by(n_parts):
    parent = np.concatenate([[-1], np.arange(n_parts - 1) // 2])
    return neighbour_parts(parent)


def _astuple(r):
    return r.part_id, r.depth, r.full_area, r.visible_area


def _assert_same(got, ref):
    assert got is not None
    for name, x, y in zip(("part_id", "depth", "full_area", "visible_area"), got, ref, strict=True):
        assert x.dtype == y.dtype and x.shape == y.shape, name
        assert np.array_equal(x, y), f"{name} differs"


@needs_compiled
@pytest.mark.parametrize("outer", ["plain", "outer_only", "buried_by"])
def test_compiled_matches_numpy_bit_for_bit(outer):
    n_parts = 8
    kw = {"outer_only": outer != "plain", "buried_by": None}
    if outer == "buried_by":
        kw["buried_by"] = _buried_by(n_parts)
    for k, cam in enumerate(_cameras()):
        body = _body(cam, seed=k)
        rays = camera_rays(cam)
        ref = render_kernel.render_numpy(cam, *body, n_parts, rays=rays, **kw)
        got = render_kernel.render_compiled(cam, *body, n_parts, rays=rays, **kw, check=False)
        _assert_same(got, ref)
        part_id, depth, full_area, visible_area = ref
        # the body is seen, occluded in places, and part n_parts - 1 nowhere
        assert (part_id >= 0).sum() > 2000 and np.isfinite(depth).sum() == (part_id >= 0).sum()
        assert full_area[-1] == visible_area[-1] == 0
        assert (visible_area[:-1] < full_area[:-1]).any()
        assert visible_area.sum() == (part_id >= 0).sum()


@needs_compiled
def test_without_precomputed_rays():
    cam = _cameras()[3]  # with distortion
    body = _body(cam, seed=11, n=25)
    for kw in ({}, {"outer_only": True}):
        ref = render_kernel.render_numpy(cam, *body, **kw)
        _assert_same(render_kernel.render_compiled(cam, *body, **kw, check=False), ref)
        _assert_same(render_kernel.render_compiled(cam, *body, rays=camera_rays(cam), **kw), ref)


@needs_compiled
def test_more_than_64_parts():
    """Over 64 parts the areas ignoring occlusion are not tracked (all zero), both ways."""
    cam = _cameras()[1]
    centers, axes, radii, _ = _body(cam, seed=5, n=30)
    part = np.arange(30) * 2 + 10  # parts 10..68 of 70
    for outer_only in (False, True):
        args = (cam, centers, axes, radii, part, 70)
        ref = render_kernel.render_numpy(*args, outer_only=outer_only)
        _assert_same(render_kernel.render_compiled(*args, outer_only=outer_only, check=False), ref)
        assert not ref[2].any() and ref[3].sum() > 0


@needs_compiled
@pytest.mark.parametrize("size", [(1, 384), (512, 1)])
def test_one_pixel_wide_or_high_image(size):
    """A one-pixel-wide image: every box is one pixel wide; one pixel high: one row per
    box (edge cases of the box loops)."""
    full = _cameras()[0]
    K = full.K.copy()
    K[:2, 2] = [0.0 if size[0] == 1 else K[0, 2], 0.0 if size[1] == 1 else K[1, 2]]
    cam = Camera("thin", size, K, np.zeros(5), full.R, full.t)
    rng = np.random.default_rng(2)
    n = 30
    uv = np.column_stack([rng.uniform(-0.5, 0.5, n), rng.uniform(-20, 404, n)])
    if size[1] == 1:
        uv = uv[:, ::-1] * [512 / 404, 1.0]
    _, d = cam.rays(uv)
    centers = cam.center + 7.0 * d / (d @ cam.R[2])[:, None]
    axes = np.linalg.qr(rng.normal(size=(n, 3, 3)))[0]
    radii = rng.uniform(0.03, 0.2, (n, 3))
    part = rng.integers(0, 5, n)
    for outer_only in (False, True):
        args = (cam, centers, axes, radii, part, 5)
        ref = render_kernel.render_numpy(*args, outer_only=outer_only)
        _assert_same(render_kernel.render_compiled(*args, outer_only=outer_only, check=False), ref)
        assert (ref[0] >= 0).sum() > 20


def test_render_parts_is_the_numpy_path_bit_for_bit(monkeypatch):
    """``render_parts`` gives the numpy path's arrays, compiled or not (numba missing or
    switched off): the numpy path is tested without numba too."""
    cam = _cameras()[2]
    centers, axes, radii, part = _body(cam, seed=3, n=20)
    rays = camera_rays(cam)
    args = (cam, centers, axes, radii, part, 8)
    for kw in ({}, {"outer_only": True, "buried_by": _buried_by(8)}):
        ref = render_kernel.render_numpy(*args, rays=rays, **kw)
        _assert_same(_astuple(render_parts(*args, rays=rays, **kw)), ref)
        with monkeypatch.context() as m:
            m.setenv("SOMACAP_NO_NUMBA", "1")
            assert render_kernel.render_compiled(*args, rays=rays, **kw) is None
            _assert_same(_astuple(render_parts(*args, rays=rays, **kw)), ref)


def test_rays_not_contiguous_fall_back_to_numpy():
    """Rays numpy multiplies by other code paths (not C-contiguous) go to the numpy path."""
    cam = _cameras()[0]
    centers, axes, radii, part = _body(cam, seed=4, n=15)
    w, h = cam.size
    rays4 = np.zeros((h, w, 4))
    rays4[..., :3] = camera_rays(cam)
    rays = rays4[..., :3]
    args = (cam, centers, axes, radii, part, 8)
    assert render_kernel.render_compiled(*args, rays=rays) is None
    _assert_same(_astuple(render_parts(*args, rays=rays)), render_kernel.render_numpy(*args))


def test_no_ellipsoids_and_parts_out_of_range():
    cam = _cameras()[0]
    w, h = cam.size
    empty = (np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros(0, int), 3)
    for fn in (render_kernel.render_numpy, render_kernel.render_compiled):
        out = fn(cam, *empty)
        if out is None:  # compiled path off
            continue
        part_id, depth, full_area, visible_area = out
        assert (part_id == -1).all() and np.isinf(depth).all() and part_id.shape == (h, w)
        assert full_area.tolist() == visible_area.tolist() == [0, 0, 0]
    centers, axes, radii, part = _body(cam, seed=6, n=5)
    assert render_kernel.render_compiled(cam, centers, axes, radii, part + 8, 8) is None


def _reference_box(uv, cam_z, w, h):
    """The box of :func:`render_kernel.render_numpy`'s loop for one ellipsoid."""
    if np.any(cam_z <= 1e-6) or not np.all(np.isfinite(uv)):
        return 0, 0, w - 1, h - 1
    u0 = max(int(np.floor(uv[:, 0].min())) - 1, 0)
    v0 = max(int(np.floor(uv[:, 1].min())) - 1, 0)
    u1 = min(int(np.ceil(uv[:, 0].max())) + 1, w - 1)
    v1 = min(int(np.ceil(uv[:, 1].max())) + 1, h - 1)
    return u0, v0, u1, v1


def test_boxes_are_the_reference_boxes():
    """The compiled path's stacked boxes equal the reference's per-ellipsoid ones, empty
    ones included (far outside, huge or non-finite projections, behind the camera)."""
    rng = np.random.default_rng(8)
    w, h = 512, 384
    uv = rng.uniform(-30, 550, (400, 8, 2))
    uv[:50] *= 1e18  # huge
    uv[50:60, 3, 1] = np.nan
    uv[60:70, 5, 0] = np.inf
    uv[70:80] = rng.uniform(511.2, 513.5, (10, 8, 2))  # one pixel wide or high, or none
    uv[80:90] = rng.uniform(-2.5, 0.9, (10, 8, 2))
    cam_z = rng.uniform(0.5, 9.0, (400, 8))
    cam_z[90:100, 2] = rng.uniform(-1.0, 1e-6, 10)
    got = render_kernel._boxes(uv, cam_z, w, h)
    ref = [_reference_box(uv[e], cam_z[e], w, h) for e in range(len(uv))]
    live = [u0 <= u1 and v0 <= v1 for u0, v0, u1, v1 in ref]
    got_live = (got[:, 0] <= got[:, 2]) & (got[:, 1] <= got[:, 3])
    np.testing.assert_array_equal(got_live, live)
    np.testing.assert_array_equal(got[got_live], np.array(ref)[live])
    assert 0 < sum(live) < len(live)


@needs_compiled
def test_buried_test_sums_as_outer():
    """The compiled buried-surface test sums ``|A (x − c)|²`` as ``_outer`` does, to the
    last bit (a last-bit difference flips its ``< shrink²`` only rarely, so the renders
    above would not show it)."""
    rng = np.random.default_rng(9)
    A_all = rng.normal(size=(7, 3, 3)) * 8.0
    centers = rng.normal(size=(7, 3))
    others = np.array([0, 2, 3, 6])
    x = rng.normal(size=(13, 17, 3))
    # as render_kernel._outer
    y = x[:, :, None, :] - centers[others]
    dot3 = render_kernel._dot3
    q = [dot3(y[..., 0], y[..., 1], y[..., 2], A_all[others][:, i].T) for i in range(3)]
    ref = dot3(*q, q)
    got = np.array(
        [
            [
                [render_kernel._norm2_in(*x[i, j], A_all[o], centers[o]) for o in others]
                for j in range(17)
            ]
            for i in range(13)
        ]
    )
    assert np.array_equal(got, ref)


def test_compiled_path_is_on_wherever_numba_is():
    """The reference sums elementwise, in the compiled loops' order, so the compiled
    path agrees with it on every CPU (with numpy's BLAS products it was off on AVX-512
    machines, whose ``dgemv`` sums in another order)."""
    if not field_kernel.enabled():
        pytest.skip("numba missing or switched off")
    assert render_kernel.agrees()


def test_reference_does_not_depend_on_alignment():
    """The same rays in a buffer shifted by one float64 (another alignment for SIMD and
    BLAS kernels) render to the same bits."""
    cam = _cameras()[2]
    body = _body(cam, seed=4, n=30)
    rays = camera_rays(cam)
    buf = np.empty(rays.size + 1)
    shifted = buf[1:].reshape(rays.shape)
    shifted[...] = rays
    for outer_only in (False, True):
        ref = render_kernel.render_numpy(cam, *body, 8, rays=rays, outer_only=outer_only)
        got = render_kernel.render_numpy(cam, *body, 8, rays=shifted, outer_only=outer_only)
        _assert_same(got, ref)


@needs_compiled
def test_degenerate_rays():
    """Zero and NaN viewing directions (a lens model overflowing far outside the image):
    IEEE results as numpy's, no exception that would switch the compiled paths off."""
    cam = _cameras()[0]
    body = _body(cam, seed=12, n=20)
    rays = camera_rays(cam)
    rays[::7, ::5] = 0.0
    rays[3::11, 2::9] = np.nan
    for kw in ({}, {"outer_only": True}):
        with np.errstate(divide="ignore", invalid="ignore"):  # numpy warns: 0 / 0
            ref = render_kernel.render_numpy(cam, *body, rays=rays, **kw)
        _assert_same(render_kernel.render_compiled(cam, *body, rays=rays, **kw, check=False), ref)
    assert field_kernel.enabled()
