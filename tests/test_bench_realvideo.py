"""The real-video benchmark's held-out-camera check, on a synthetic textured plane."""

import cv2
import numpy as np

from bench.realvideo import check_in_camera, facing
from tests.core.wand_truth import look_at

SIZE = (320, 240)


def _render_plane(cam, texture, metres_per_px):
    """Image of the textured plane y = 0 (texture centred on the origin) in ``cam``."""
    h, w = texture.shape
    T = np.array(
        [
            [metres_per_px, 0, -w / 2 * metres_per_px],
            [0, metres_per_px, -h / 2 * metres_per_px],
            [0, 0, 1.0],
        ]
    )
    H = cam.K @ np.column_stack([cam.R[:, 0], cam.R[:, 2], cam.t]) @ T
    return cv2.warpPerspective(
        texture, H, SIZE, flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT
    )


def _scene(seed=0):
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.uniform(0, 255, (400, 400)).astype(np.float32), (0, 0), 2.0)
    tex = cv2.normalize(tex, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    cams = [
        look_at(n, c, (0, 0, 0), size=SIZE, f=400.0)
        for n, c in (
            ("a", (-0.9, -2.0, 0.3)),
            ("b", (0.5, -2.0, 0.2)),
            ("chk", (1.6, -1.4, -0.3)),
            ("back", (0.2, 2.0, 0.1)),
        )
    ]
    imgs = [_render_plane(c, tex, 0.002) for c in cams]
    g = np.linspace(-0.12, 0.12, 7)
    xyz = np.array([[x, 0.0, z] for x in g for z in g])
    return cams, imgs, xyz


def test_facing_turns_the_normal_to_the_given_point():
    _, _, xyz = _scene()
    n = facing(xyz, np.tile([0.0, -3.0, 0.5], (len(xyz), 1)))
    assert np.allclose(n, [0, -1, 0], atol=1e-9)
    n = facing(xyz, np.tile([0.3, 3.0, 0.0], (len(xyz), 1)))
    assert np.allclose(n, [0, 1, 0], atol=1e-9)


def test_held_out_camera_finds_true_points_where_projected_and_skips_hidden_ones():
    cams, imgs, xyz = _scene()
    uv = np.stack([c.project(xyz) for c in cams[:2]], axis=1)[None]  # (1, P, 2, 2)
    uv[0, ::2, 1] = np.nan  # half the points measured in camera a only
    videos = [im[None] for im in imgs[:2]]
    dist, tried = check_in_camera(imgs[2][None], videos, cams[2], cams[:2], xyz[None], uv, half=6)
    assert tried.all()
    d = dist[np.isfinite(dist)]
    assert d.size >= 0.9 * xyz.shape[0]
    assert np.median(d) < 0.1 and d.max() < 0.3
    # a wrong 3-D position shows as its image offset
    off = xyz + [0.0, 0.0, 0.005]  # 5 mm along z: ~0.9 px
    shift = np.linalg.norm(cams[2].project(off) - cams[2].project(xyz), axis=1)
    dist_off, _ = check_in_camera(imgs[2][None], videos, cams[2], cams[:2], off[None], uv, half=6)
    ok = np.isfinite(dist_off[0])
    assert ok.sum() >= 0.8 * xyz.shape[0]
    assert np.allclose(dist_off[0, ok], shift[ok], atol=0.1)
    # the plane's back faces the fourth camera: nothing is tried there
    dist_b, tried_b = check_in_camera(
        imgs[3][None], videos, cams[3], cams[:2], xyz[None], uv, half=6
    )
    assert not tried_b.any() and not np.isfinite(dist_b).any()


def test_across_a_wide_angle_the_plane_warp_lets_the_match_converge():
    cams, imgs, xyz = _scene()
    wide = look_at("wide", (1.85, -0.75, 0.1), (0, 0, 0), size=SIZE, f=400.0)  # ~68° off
    rng = np.random.default_rng(1)
    tex = cv2.GaussianBlur(rng.uniform(0, 255, (400, 400)).astype(np.float32), (0, 0), 2.0)
    tex = cv2.normalize(tex, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    imgs = [_render_plane(c, tex, 0.002) for c in (*cams[:2], wide)]
    uv = np.stack([c.project(xyz) for c in cams[:2]], axis=1)[None]
    videos = [im[None] for im in imgs[:2]]
    found = {}
    for warp in (False, True):
        dist, tried = check_in_camera(
            imgs[2][None], videos, wide, cams[:2], xyz[None], uv, half=6, warp=warp
        )
        assert tried.all()
        found[warp] = dist[np.isfinite(dist)]
    assert found[True].size >= 0.9 * len(xyz)
    assert np.median(found[True]) < 0.1
    assert found[False].size < 0.5 * found[True].size
