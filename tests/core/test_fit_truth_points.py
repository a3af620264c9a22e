"""Truth-derived observations: exact depth maps, visibility of convex and occluded
surfaces (the stand-in for tracked points that the fit benchmarks use)."""

import numpy as np

from core.camera import Camera
from core.truth_points import depth_map, sample_frame, visible


def _sphere(center, radius, n_lat=24, n_lon=48):
    """UV sphere: vertices (V, 3) and outward counter-clockwise faces (T, 3)."""
    lat = np.linspace(0, np.pi, n_lat + 1)[1:-1]
    lon = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    v = np.stack([np.sin(la) * np.cos(lo), np.sin(la) * np.sin(lo), np.cos(la)], -1)
    v = np.concatenate([[[0, 0, 1]], v.reshape(-1, 3), [[0, 0, -1]]])
    faces = []
    ring = lambda i, j: 1 + i * n_lon + j % n_lon  # noqa: E731
    for j in range(n_lon):
        faces.append((0, ring(0, j), ring(0, j + 1)))
        faces.append((len(v) - 1, ring(n_lat - 2, j + 1), ring(n_lat - 2, j)))
        for i in range(n_lat - 2):
            a, b = ring(i, j), ring(i, j + 1)
            c, d = ring(i + 1, j), ring(i + 1, j + 1)
            faces += [(a, c, b), (b, c, d)]
    return np.asarray(center) + radius * v, np.array(faces)


def _camera(center, size=(320, 240), f=400.0):
    """A camera at ``center`` looking at the world origin (z up)."""
    c = np.asarray(center, float)
    z = -c / np.linalg.norm(c)
    x = np.cross(z, [0, 0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    K = [[f, 0, (size[0] - 1) / 2], [0, f, (size[1] - 1) / 2], [0, 0, 1]]
    return Camera("cam", size, K, np.zeros(5), R, -R @ c)


def test_depth_map_of_a_sphere_matches_ray_casting():
    v, faces = _sphere([0, 0, 0], 0.5, 32, 64)
    cam = _camera([0, -4.0, 0])
    zmap = depth_map(cam, v[faces])
    h, w = zmap.shape
    u, vv = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    o, d = cam.rays(np.stack([u, vv], -1).reshape(-1, 2))
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    b = d @ o  # ray-sphere intersection, sphere of radius 0.5 at the origin
    disc = b**2 - (o @ o - 0.25)
    hit = disc > 0
    tt = -b - np.sqrt(np.where(hit, disc, 0))
    z_true = np.where(hit, (cam.to_camera(o + tt[:, None] * d))[:, 2], np.inf).reshape(h, w)
    both = np.isfinite(z_true) & np.isfinite(zmap)
    assert (np.isfinite(z_true) != np.isfinite(zmap)).sum() < 0.03 * np.isfinite(z_true).sum()
    # the facets lie inside the true sphere by up to their sagitta r(1 - cos(pi/32)),
    # 2.4 mm; more only at the grazing rim
    err = np.abs(zmap[both] - z_true[both])
    assert np.median(err) < 0.0024 and np.percentile(err, 90) < 0.004


def test_a_convex_surface_is_seen_wherever_it_faces_the_camera(rng):
    v, faces = _sphere([0, 0, 0], 0.5)
    cam = _camera([0.3, -4.0, 0.5])
    tri = v[faces]
    t = rng.integers(0, len(faces), 4000)
    a, b = rng.random((2, len(t))) * 0.5
    pts = tri[t, 0] + a[:, None] * (tri[t, 1] - tri[t, 0]) + b[:, None] * (tri[t, 2] - tri[t, 0])
    nrm = np.cross(tri[t, 1] - tri[t, 0], tri[t, 2] - tri[t, 0])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    seen = visible(cam, pts, nrm, depth_map(cam, tri), max_angle_deg=80.0)
    view = cam.center - pts
    cos = np.einsum("ij,ij->i", view, nrm) / np.linalg.norm(view, axis=1)
    expected = cos > np.cos(np.radians(80.0))
    assert expected.sum() > 1000
    assert np.mean(seen == expected) > 0.995


def test_an_occluder_hides_what_lies_behind_it(rng):
    v1, f1 = _sphere([0, 0, 0], 0.5)
    v2, f2 = _sphere([0, -1.0, 0], 0.2)  # in front of the big sphere, seen from -y
    v = np.concatenate([v1, v2])
    faces = np.concatenate([f1, f2 + len(v1)])
    cam = _camera([0, -4.0, 0])
    xyz, bad = sample_frame(v, faces, [cam, cam], 6000, rng, noise_m=0.0, outliers=0.0)
    assert not bad.any() and len(xyz) > 1000
    on_big = np.abs(np.linalg.norm(xyz, axis=1) - 0.5) < 0.01
    # the shadow of the small sphere on the big one, seen from the camera
    c = cam.center
    d = xyz - c
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    to_small = np.array([0, -1.0, 0]) - c
    dist_axis = np.linalg.norm(np.cross(d, to_small), axis=1)
    shadow = dist_axis < 0.19
    assert (on_big & ~shadow).sum() > 500
    assert (on_big & shadow).sum() == 0
    assert np.all(xyz[:, 1] < 0.01)  # nothing of the back halves
