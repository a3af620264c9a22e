"""The benchmark's studio clip windows lie inside their clips and show their motion."""

import numpy as np

from bench.fit import FPS, FRAMES, STUDIO_SCENES
from sample_scenes.bvh import read_bvh

CMU_SCALE = 0.056444  # CMU units -> metres (../shared/data/README.md)


def _window(shared_data, name):
    bvh_name, _, start = STUDIO_SCENES[name]
    bvh = read_bvh(shared_data / "mocap" / bvh_name)
    end = start + round((FRAMES - 1) / FPS / bvh.frame_time)
    assert end < bvh.n_frames
    return bvh.root_positions(CMU_SCALE)[start : end + 1]


def test_every_window_fits_its_clip(shared_data):
    for name in STUDIO_SCENES:
        _window(shared_data, name)


def test_jump_window_holds_a_jump(shared_data):
    hips = _window(shared_data, "jumps_line3")
    up = hips[:, 2]
    # standing at the start, hips well above standing height in flight, forward motion
    assert up.max() - up[0] > 0.15
    assert np.linalg.norm(hips[-1, :2] - hips[0, :2]) > 0.3


def test_default_dance_windows_start_upright(shared_data):
    from bench.fit import DEFAULT_SET

    for name in DEFAULT_SET:
        bvh_name, _, start = STUDIO_SCENES[name]
        if bvh_name != "05_06.bvh":
            continue
        bvh = read_bvh(shared_data / "mocap" / bvh_name)
        _, xyz = bvh.sample(np.array([start * bvh.frame_time]), CMU_SCALE)
        assert xyz[0, bvh.index("Head"), 2] - xyz[0, bvh.index("Hips"), 2] > 0.3


def _uv_sphere(center, radius, n_lat=48, n_lon=64, crowd=3.0):
    """Vertices (V, 3) and triangles (T, 3) of a UV sphere whose rings crowd towards
    the north pole (latitude spacing ∝ t**crowd): most vertices on a small cap."""
    t = np.linspace(0.0, 1.0, n_lat + 1)[1:-1]
    polar = np.pi * t**crowd
    lon = np.linspace(0.0, 2 * np.pi, n_lon, endpoint=False)
    P, L = np.meshgrid(polar, lon, indexing="ij")
    ring = np.stack([np.sin(P) * np.cos(L), np.sin(P) * np.sin(L), np.cos(P)], -1).reshape(-1, 3)
    v = np.vstack([[0, 0, 1.0], ring, [0, 0, -1.0]]) * radius + center
    idx = 1 + np.arange(len(polar) * n_lon).reshape(len(polar), n_lon)
    tri = [[0, idx[0, j], idx[0, (j + 1) % n_lon]] for j in range(n_lon)]
    for i in range(len(polar) - 1):
        for j in range(n_lon):
            a, b = idx[i, j], idx[i, (j + 1) % n_lon]
            c, d = idx[i + 1, j], idx[i + 1, (j + 1) % n_lon]
            tri += [[a, c, b], [b, c, d]]
    south = len(v) - 1
    tri += [[idx[-1, j], south, idx[-1, (j + 1) % n_lon]] for j in range(n_lon)]
    return v, np.array(tri)


def test_surface_distance_samples_the_mesh_by_area():
    """One spherical metaball against a sphere mesh whose vertices crowd on a cap: the
    distance by area is ~0 for the same radius and 10 mm for a sphere 1 cm larger
    (a vertex mean would not see the crowding; the area sampling does not care)."""
    from core import metaballs as mb
    from core import skeleton as sk
    from core.evaluate import surface_distance_mm
    from core.state import FitState, Quality

    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    r = 0.1
    balls = mb.Metaballs(
        np.array([skel.bone_index("pelvis")]),
        np.zeros((1, 3)),
        np.array([-1]),
        np.eye(3)[None],
        np.full((1, 3), r / mb.VISIBLE),
    )
    theta, root = np.zeros((1, skel.n_dof)), np.array([[0.0, 0.0, 1.0]])
    state = FitState(
        skeleton=skel,
        s=s,
        metaballs=balls,
        root_xyz=root,
        theta=theta,
        quality=Quality.empty(1, skel.n_dof),
    )
    _, cw = mb.world_frames(skel, sk.forward(skel, theta, root, s), balls, s)
    for radius, want in ((r, 0.0), (r + 0.01, 10.0)):
        v, tri = _uv_sphere(cw[0, 0], radius)
        assert (np.linalg.norm(v[:, :2] - cw[0, 0, :2], axis=1) < 0.5 * radius).mean() > 0.5
        d = surface_distance_mm(state, v[None], tri, [0])
        assert abs(d - want) < 0.3, (radius, d)


def test_tracked_point_errors_follow_the_material_points():
    """A sphere that moves and turns: points carried with it are 0 mm off; a trajectory
    that jumps 8 cm is counted gross from that frame; removed, unmeasured and NaN
    point-frames are not compared."""
    from bench.tracking import tracked_point_errors

    rng = np.random.default_rng(3)
    v0, tri = _uv_sphere(np.zeros(3), 0.1, crowd=1.0)
    F, P = 6, 40
    verts, pts = [], []
    p0 = v0[rng.choice(len(v0), P, replace=False)]
    for f in range(F):
        a = 0.2 * f
        R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]])
        move = np.array([0.05 * f, 0.0, 1.0])
        verts.append(v0 @ R.T + move)
        pts.append(p0 @ R.T + move)
    xyz = np.array(pts)
    xyz[3:, 0] += np.array([0.08, 0.0, 0.0])  # trajectory 0 slips onto another place
    removed = np.zeros(P, bool)
    removed[1] = True
    xyz[:, 1] += 0.5  # a removed trajectory far off: not counted
    measured = np.ones((F, P), bool)
    measured[2, 2] = False
    xyz[2, 2] = np.nan
    tracks = {"xyz": xyz, "start": np.zeros(P, int), "measured": measured, "removed": removed}
    t = tracked_point_errors(tracks, np.array(verts), tri)
    assert t["n"] == F * (P - 1) - 1
    assert t["median_mm"] < 1e-6
    np.testing.assert_allclose(t["gross_pct"], 100 * 3 / t["n"])
    assert t["worst_frame"] >= 3
    np.testing.assert_allclose(t["worst_frame_mean_mm"], 80.0 / (P - 1), rtol=1e-6)
    assert tracked_point_errors({**tracks, "removed": np.ones(P, bool)}, np.array(verts), tri) == {
        "n": 0
    }
