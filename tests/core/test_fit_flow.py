"""Single-camera texture flow on the fitted body (core.fit_flow).

The images are rendered from the model itself with a texture fixed in each bone's frame
(:func:`tests.core._bodyscene.textured_render`), so a corner's true motion is the body's
motion.
"""

import numpy as np

from core.fit_flow import (
    FlowAnchors,
    FlowObs,
    FlowSettings,
    follow_corners,
    lift_corners,
    refine_corners,
    render_body,
)
from core.fit_reference import visible_points
from core.fitting import FitSettings, Observations, fit
from core.metaballs import make_metaballs, world_frames
from core.model_render import camera_rays, render_parts
from core.skeleton import bone_frames, forward, joint_positions, make_skeleton, points_world

from ._bodyscene import cameras, clicks_of, look_at
from ._bodyscene import textured_render as _textured


def _body():
    skel = make_skeleton()
    s = np.ones(skel.n_groups)
    balls = make_metaballs(skel, "simplified", s)
    theta0 = np.zeros(skel.n_dof)
    for d, a in (
        ("l_shoulder_x", 0.3),
        ("r_shoulder_x", -0.2),
        ("l_elbow_x", -0.4),
        ("l_hip_x", 0.2),
        ("r_hip_x", -0.2),
        ("r_knee_x", 0.3),
    ):
        if d in skel.dof_names:
            theta0[skel.dof_index(d)] = a
    return skel, s, balls, theta0, np.array([0.0, 0.0, 1.0])


def test_block_jacobians_match_finite_differences():
    skel, s, _, theta, root = _body()
    rng = np.random.default_rng(1)
    cams = cameras()
    K = 30
    bone = rng.integers(0, len(skel.bone_names), K)
    q0 = rng.normal(0.0, 0.05, (K, 3))
    cam = rng.integers(0, len(cams), K)
    pose = forward(skel, theta[None], root[None], s)
    x = points_world(skel, pose, bone, q0, np.full(K, -1), s)[0]
    uv = np.array([cams[c].project(x[i][None])[0] for i, c in enumerate(cam)])
    obs = FlowObs(cams, bone, q0, cam, uv + rng.normal(0, 2.0, uv.shape), np.full(K, 1.0))
    obs.freeze(skel, theta, root, s)
    r, Jt, Jr, Js, _, _ = obs.block(skel, theta, root, s)
    h = 1e-6
    for k in rng.choice(skel.n_dof, 8, replace=False):
        d = np.zeros(skel.n_dof)
        d[k] = h
        fd = obs.block(skel, theta + d, root, s)[0] - obs.block(skel, theta - d, root, s)[0]
        np.testing.assert_allclose(fd / (2 * h), Jt[:, k], atol=1e-5 * np.abs(Jt).max())
    for k in range(3):
        d = np.zeros(3)
        d[k] = h
        fd = obs.block(skel, theta, root + d, s)[0] - obs.block(skel, theta, root - d, s)[0]
        np.testing.assert_allclose(fd / (2 * h), Jr[:, k], atol=1e-5 * np.abs(Jr).max())
    for g in range(skel.n_groups):
        d = np.zeros(skel.n_groups)
        d[g] = h
        fd = obs.block(skel, theta, root, s + d)[0] - obs.block(skel, theta, root, s - d)[0]
        np.testing.assert_allclose(fd / (2 * h), Js[:, g], atol=1e-5 * max(np.abs(Js).max(), 1))


def test_lifted_corners_lie_on_the_rendered_body_and_project_back():
    skel, s, balls, theta, root = _body()
    cam = cameras()[1]
    rays = camera_rays(cam)
    img = _textured(skel, balls, theta, root, s, cam, rays)
    uv, bone, q0 = lift_corners(skel, balls, theta, root, s, cam, img, None, FlowSettings(), rays)
    assert len(uv) > 100 and len(np.unique(bone)) >= 12, (len(uv), len(np.unique(bone)))
    pose = forward(skel, theta[None], root[None], s)
    x = points_world(skel, pose, bone, q0, np.full(len(bone), -1), s)[0]
    np.testing.assert_allclose(cam.project(x), uv, atol=0.02)
    # on the surface of one of its part's ellipsoids (the rendered ones)
    Rw, cw = world_frames(skel, pose, balls, s)
    d = np.full(len(x), np.inf)
    for e in range(len(balls.bone)):
        on = bone == balls.bone[e]
        y = (x[on] - cw[0, e]) @ Rw[0, e] / balls.visible[e]
        d[on] = np.minimum(d[on], np.abs(np.linalg.norm(y, axis=1) - 1.0))
    assert np.median(d) < 0.05


def test_followed_corners_recover_the_next_pose():
    """Corners lifted at the true previous pose and followed into the next frame's
    images bring a pose started at the previous one to the true next pose."""
    skel, s, balls, theta0, root0 = _body()
    cams = cameras()
    rays = [camera_rays(c) for c in cams]
    theta1 = theta0.copy()
    for d, a in (
        ("r_shoulder_x", 0.08),
        ("r_elbow_x", 0.1),
        ("r_hip_x", 0.06),
        ("r_knee_x", -0.08),
        ("l_hip_x", -0.05),
    ):
        theta1[skel.dof_index(d)] += a
    root1 = root0 + np.array([0.012, -0.008, 0.0])
    imgs = {
        (c, f): _textured(skel, balls, th, rt, s, cam, rays[c])
        for c, cam in enumerate(cams)
        for f, th, rt in ((0, theta0, root0), (1, theta1, root1))
    }
    anchors = FlowAnchors(cams, lambda c, f: imgs[c, f], FlowSettings(), rays=rays)
    anchors.set(skel, balls, theta0, root0, s, 0)
    assert anchors.observations(5) is None  # only the next or the previous frame
    obs = anchors.observations(1)
    assert obs is anchors.observations(1)  # followed once per frame
    assert len(obs) > 300
    cfg = FitSettings(irls_rounds=3, max_nfev=50, use_limits=False)
    o = Observations(flow=obs, theta_pred=theta0, sigma_pred=1.0)
    r = fit(skel, balls, o, theta0, root0, s, solve="pose", settings=cfg)
    j1 = joint_positions(skel, theta1, root1, s)
    err0 = np.linalg.norm(joint_positions(skel, theta0, root0, s) - j1, axis=1)
    err = np.linalg.norm(joint_positions(skel, r.theta, r.root_xyz, s) - j1, axis=1)
    assert err0.max() > 0.03
    assert np.median(err) < 0.003 and np.percentile(err, 90) < 0.008, (err0, err)


def test_follow_corners_rejects_what_it_cannot_follow():
    rng = np.random.default_rng(4)
    img0 = (rng.random((120, 160)) * 255).astype(np.uint8)
    img0 = np.asarray(np.clip(np.kron(img0[::4, ::4], np.ones((4, 4))), 0, 255), np.uint8)[
        :120, :160
    ]
    img1 = np.roll(img0, (2, 3), axis=(0, 1))  # moved by (3, 2) px
    flat = np.full_like(img0, 100)
    uv = np.array([[60.0, 60.0], [80.0, 50.0], [158.5, 60.0]])
    uv1, ok = follow_corners(img0, img1, uv, FlowSettings())
    assert ok[0] and ok[1]
    np.testing.assert_allclose(uv1[ok] - uv[ok], [[3.0, 2.0]] * int(ok.sum()), atol=0.1)
    _, ok_flat = follow_corners(img0, flat, uv, FlowSettings())
    assert not ok_flat.any()  # the texture vanished: nothing is followed
    assert follow_corners(img0, img1, np.zeros((0, 2)), FlowSettings())[0].shape == (0, 2)


def test_persistent_corners_keep_their_points_and_drop_when_they_slip():
    """Corners followed into the next frame keep the surface point they were lifted
    at; one that no longer projects near its point (slipped onto another surface) is
    dropped and the part is filled with fresh corners."""
    skel, s, balls, theta0, root0 = _body()
    cams = cameras()[1:2]
    rays = [camera_rays(c) for c in cams]
    theta1 = theta0.copy()
    theta1[skel.dof_index("r_hip_x")] += 0.05
    root1 = root0 + np.array([0.01, 0.0, 0.0])
    imgs = {
        (0, 0): _textured(skel, balls, theta0, root0, s, cams[0], rays[0]),
        (0, 1): _textured(skel, balls, theta1, root1, s, cams[0], rays[0]),
    }
    a = FlowAnchors(cams, lambda c, f: imgs[c, f], FlowSettings(), rays=rays)
    a.set(skel, balls, theta0, root0, s, 0)
    uv0, b0, q00 = a._lifted[0]
    obs = a.observations(1)
    followed_uv, followed_b, followed_q = a._followed[1][0]
    followed_uv[0] += 10.0  # this one slipped 10 px off its point
    a.set(skel, balls, theta1, root1, s, 1)
    uv1, b1, q01 = a._lifted[0]
    n_kept = (
        len(obs)
        - 1
        - np.sum(
            ~_kept_mask(
                skel,
                balls,
                theta1,
                root1,
                s,
                cams[0],
                rays[0],
                followed_uv[1:],
                followed_b[1:],
                followed_q[1:],
            )
        )
    )
    assert n_kept > 0.8 * len(obs)
    # the kept corners come first, with their frame-0 points unchanged
    np.testing.assert_array_equal(q01[:n_kept], followed_q[1:][:n_kept])
    assert not np.any(np.all(np.isclose(q01, followed_q[0]), axis=1))  # the slipped one
    assert len(uv1) > n_kept  # fresh corners fill the parts
    a2 = FlowAnchors(cams, lambda c, f: imgs[c, f], FlowSettings(persist=False), rays=rays)
    a2.set(skel, balls, theta0, root0, s, 0)
    a2.observations(1)
    a2.set(skel, balls, theta1, root1, s, 1)
    assert not np.any(np.all(np.isin(a2._lifted[0][2], q00), axis=1))  # all lifted afresh


def _kept_mask(skel, balls, theta, root, s, cam, rays, uv, bone, q0):
    """Which followed corners lift_corners keeps (its rule, restated)."""
    pose = forward(skel, theta[None], root[None], s)
    Rw, cw = world_frames(skel, pose, balls, s)
    ren = render_parts(
        cam, cw[0], Rw[0], balls.visible, balls.bone, len(skel.bone_names), rays=rays
    )
    x = points_world(skel, pose, bone, q0, np.full(len(bone), -1), s)[0]
    iu, iv = np.rint(uv).astype(int).T
    return (np.linalg.norm(cam.project(x) - uv, axis=1) <= FlowSettings().keep_px) & (
        ren.part_id[iv, iu] == bone
    )


def test_sequence_without_points_follows_the_texture_where_the_outline_misleads():
    """No 3-D points, contours from a body 12 % thicker than the model (its outline
    pulls the model's parts), texture flow in every camera: fit_sequence with the flow
    follows the true joints closer than with the contours alone (5.6 vs 7.3 mm)."""
    from core.fit import FramePoints, SequenceSettings, fit_sequence
    from core.fit_contours import ContourSettings, contour_frames
    from core.fit_init import initialise
    from core.landmarks import CLICK_JOINTS, METRIC_JOINTS

    from ._contourscene import _cams, _silhouettes

    skel, s, balls, theta0, root0 = _body()
    nf = 5
    theta = np.repeat(theta0[None], nf, axis=0)
    for d, a in (("r_shoulder_x", 0.25), ("l_hip_x", -0.2), ("r_knee_x", 0.25), ("spine_z", 0.15)):
        theta[:, skel.dof_index(d)] += np.linspace(0.0, a, nf)
    root = root0 + np.array([[0.0, -0.02 * f, 0.0] for f in range(nf)])
    body = balls.copy(radii=balls.radii * 1.12)  # the subject is not the template
    cams = _cams()
    rays = [camera_rays(c) for c in cams]
    cons = [_silhouettes(skel, body, theta[f], root[f], s, cams) for f in range(nf)]
    imgs = {
        (c, f): _textured(skel, body, theta[f], root[f], s, cam, rays[c])
        for c, cam in enumerate(cams)
        for f in range(nf)
    }
    init = initialise(
        clicks_of(skel, theta[0], root[0], s, cams, CLICK_JOINTS), cams, model="simplified"
    )
    init.metaballs = balls.copy()
    frames = [FramePoints(np.zeros((0, 3)), np.zeros(0)) for _ in range(nf)]
    idx = [skel.joint_index(j) for j in METRIC_JOINTS]
    truth = joint_positions(skel, theta, root, s)[:, idx]
    err = {}
    for use in (False, True):
        cfr = contour_frames(cams, cons, ContourSettings())
        anchors = FlowAnchors(cams, lambda c, f: imgs[c, f], FlowSettings(), rays=rays)
        res = fit_sequence(
            frames,
            init,
            SequenceSettings(max_nfev=15, shape_frames=1, shape="template"),
            contours=cfr,
            flow=anchors if use else None,
        )
        assert not res.state.quality.diverged.any()
        err[use] = np.linalg.norm(res.state.joints_xyz()[:, idx] - truth, axis=-1)
    mean = {k: v[1:].mean() for k, v in err.items()}
    assert mean[True] < 0.85 * mean[False], mean
    assert mean[True] < 0.007, mean


def test_foreground_at_another_resolution_is_resized():
    """Masks at a quarter of the images' resolution (as the real-video bench makes them)
    limit the corners like full-size masks do."""
    skel, s, balls, theta, root = _body()
    cam = cameras()[1]
    rays = camera_rays(cam)
    img = _textured(skel, balls, theta, root, s, cam, rays)
    w, h = cam.size
    left = np.zeros((h // 4, w // 4), bool)
    left[:, : w // 8] = True  # the image's left half
    uv, _, _ = lift_corners(skel, balls, theta, root, s, cam, img, left, FlowSettings(), rays)
    every, _, _ = lift_corners(skel, balls, theta, root, s, cam, img, None, FlowSettings(), rays)
    assert 0 < len(uv) < len(every)
    assert uv[:, 0].max() < w / 2


def test_reference_corners_keep_the_clicked_frames_points_where_the_fit_drifted():
    """With ``reference``, the corners lifted onto the clicked frame are matched from
    its image into a later frame: they land on their points' true projections even
    when the pose the flow was last set to is turned 0.12 rad away from the truth,
    while the corners lifted onto that pose carry its error (the texture's
    wavelengths, 4–7 cm, bound the matches' precision here)."""
    skel, s, balls, theta0, root0 = _body()
    cams = cameras()
    rays = [camera_rays(c) for c in cams]
    yaw = skel.dof_index("pelvis_z")
    thetas = [theta0.copy() for _ in range(3)]
    for f, th in enumerate(thetas):
        th[yaw] += 0.12 * f  # the body turns 0.12 rad a frame
        th[skel.dof_index("r_knee_x")] += 0.05 * f
    roots = [root0 + np.array([0.01 * f, 0.0, 0.0]) for f in range(3)]
    imgs = {
        (c, f): _textured(skel, balls, thetas[f], roots[f], s, cam, rays[c])
        for c, cam in enumerate(cams)
        for f in range(3)
    }
    drifted = thetas[1].copy()
    drifted[yaw] += 0.12  # the fit of frame 1 turned as far again

    def residual_px(obs, ref):
        rows = np.isclose(obs.sigma, 2.5) == ref
        sub = FlowObs(
            cams, obs.bone[rows], obs.q0[rows], obs.camera[rows], obs.uv[rows], obs.sigma[rows]
        )
        r = sub.residuals(skel, thetas[2], roots[2], s, jacobians=False)[0]
        return np.linalg.norm(r, axis=1)

    cfg = FlowSettings(reference=True, reference_sigma_px=2.5)
    a = FlowAnchors(cams, lambda c, f: imgs[c, f], cfg, rays=rays)
    a.set_reference(skel, balls, thetas[0], roots[0], s, 0)
    a.set(skel, balls, drifted, roots[1], s, 1)
    obs = a.observations(2)
    ref, chain = residual_px(obs, True), residual_px(obs, False)
    assert len(ref) > 100, len(ref)
    # 0.33 / 0.82 px at the median / 90th percentile, against 1.41 / 2.23 px
    assert np.median(ref) < 0.5 and np.percentile(ref, 90) < 1.2, np.percentile(ref, [50, 90])
    assert np.median(chain) > 3 * np.median(ref), np.median(chain)  # lifted when drifted
    off = FlowSettings(reference=False, reference_sigma_px=2.5)
    plain = FlowAnchors(cams, lambda c, f: imgs[c, f], off, rays=rays)
    plain.set_reference(skel, balls, thetas[0], roots[0], s, 0)
    plain.set(skel, balls, drifted, roots[1], s, 1)
    assert not np.isclose(plain.observations(2).sigma, 2.5).any()  # switched off


def test_a_reference_corner_far_from_the_accepted_fit_is_dropped_for_good():
    """A reference corner matched into a frame whose accepted fit projects its point
    more than ``reference_drop_px`` away is not matched again."""
    skel, s, balls, theta0, root0 = _body()
    cams = cameras()[1:2]
    rays = [camera_rays(c) for c in cams]
    yaw = skel.dof_index("pelvis_z")
    thetas = [theta0.copy() for _ in range(3)]
    for f, th in enumerate(thetas):
        th[yaw] += 0.05 * f
    imgs = {(0, f): _textured(skel, balls, thetas[f], root0, s, cams[0], rays[0]) for f in range(3)}
    cfg = FlowSettings(reference_drop_px=4.0)
    alive = {}
    for turn in (0.0, 0.4):
        a = FlowAnchors(cams, lambda c, f: imgs[c, f], cfg, rays=rays)
        a.set_reference(skel, balls, thetas[0], root0, s, 0)
        a.set(skel, balls, thetas[0], root0, s, 0)
        matched = a.observations(1)
        assert np.isclose(matched.sigma, cfg.reference_sigma_px).sum() > 50
        accepted = thetas[1].copy()
        accepted[yaw] += turn  # the frame's fit, right or turned away
        a.set(skel, balls, accepted, root0, s, 1)
        alive[turn] = a.reference.alive[0, 0].copy()
        assert not np.isin(np.flatnonzero(~alive[turn]), a.reference.seen[0][2]).any()
    assert alive[0.0].all()
    assert (~alive[0.4]).sum() > 50, (~alive[0.4]).sum()


def test_reference_corners_are_matched_in_the_camera_a_turned_body_shows_them_to():
    """With ``reference_across``, a corner of one camera's clicked image is matched in
    another camera once the body has turned its surface towards that one (here 90°, a
    front camera and a side camera): on its point's true projection there.  Without it
    the side camera's own reference has turned away and gives almost nothing."""
    skel, s, balls, theta0, root0 = _body()
    cams = [look_at("front", (0.0, -4.0, 1.2)), look_at("side", (4.0, 0.0, 1.2))]
    rays = [camera_rays(c) for c in cams]
    yaw = skel.dof_index("pelvis_z")
    thetas = [theta0.copy() for _ in range(3)]
    for f, turn in enumerate((0.0, 1.45, 1.55)):  # radians
        thetas[f][yaw] += turn
    imgs = {
        (c, f): _textured(skel, balls, thetas[f], root0, s, cam, rays[c])
        for c, cam in enumerate(cams)
        for f in range(3)
    }
    rows = {}
    for across in (True, False):
        cfg = FlowSettings(reference_sigma_px=2.5, reference_across=across)
        a = FlowAnchors(cams, lambda c, f: imgs[c, f], cfg, rays=rays)
        a.set_reference(skel, balls, thetas[0], root0, s, 0)
        a.set(skel, balls, thetas[1], root0, s, 1)
        obs = a.observations(2)
        ref = np.isclose(obs.sigma, 2.5) & (obs.camera == 1)
        sub = FlowObs(
            cams, obs.bone[ref], obs.q0[ref], obs.camera[ref], obs.uv[ref], obs.sigma[ref]
        )
        rows[across] = np.linalg.norm(
            sub.residuals(skel, thetas[2], root0, s, jacobians=False)[0], axis=1
        )
    assert len(rows[True]) > 50 + 3 * len(rows[False]), (len(rows[True]), len(rows[False]))
    # 155 rows against 5, median 0.04 px
    assert np.median(rows[True]) < 0.5, np.percentile(rows[True], [50, 90])


def test_a_reference_corners_depth_along_its_clicked_ray_is_refined_from_its_matches():
    """A reference point lifted 1.5 cm too deep along its clicked ray projects right in
    its own camera but 1–2 px off in a camera that sees it 30–40° off that ray.  Its
    matches there (here at the true points' projections) at accepted poses move it
    back along the ray to within a millimetre; with ``reference_depth`` off it stays."""
    skel, s, balls, theta0, root0 = _body()
    cams = [look_at("front", (0.0, -4.0, 1.2)), look_at("side", (4.0, 0.0, 1.2))]
    rays = [camera_rays(c) for c in cams]
    yaw = skel.dof_index("pelvis_z")
    imgs = [_textured(skel, balls, theta0, root0, s, cam, rays[c]) for c, cam in enumerate(cams)]
    err = 0.015  # metres, away from the camera
    t = {}
    for refine in (True, False):
        cfg = FlowSettings(reference_depth=refine)
        a = FlowAnchors(cams, lambda c, f: imgs[c], cfg, rays=rays)
        a.set_reference(skel, balls, theta0, root0, s, 0)
        img, uv, bone, q0, tan = a.reference.ref[0]
        a.reference.ref[0] = (img, uv, bone, q0 + err * a.reference.depth[0][0], tan)
        for f, turn in ((1, 0.9), (2, 1.0)):  # radians: the side camera sees the
            th = theta0.copy()  # front 30–40° off its clicked rays
            th[yaw] += turn
            pose = forward(skel, th[None], root0[None], s)
            Rb, pb = bone_frames(skel, pose)
            x = pb[0, bone] + np.einsum("nij,nj->ni", Rb[0, bone], q0)  # the true points
            ren = render_body(skel, balls, pose, s, cams[1])
            _, seen = visible_points(skel, pose, cams[1], ren, bone, q0, 0.03)
            idx = np.flatnonzero(seen)
            # the frame's matches, at the true points' projections, then its accepted fit
            a.reference.matched[f] = {
                (0, 1): (idx, cams[1].project(x[idx]), np.zeros((len(idx), 2, 2)))
            }
            a.set(skel, balls, th, root0, s, f)
        t[refine] = a.reference.depth[0][3][idx]
    assert len(idx) > 50, len(idx)
    # median 0.0x mm off
    assert np.median(np.abs(t[True] + err)) < 0.001, np.percentile(t[True], [10, 50, 90])
    assert np.all(t[False] == 0.0)


def test_lsm_refines_what_lucas_kanade_follows_on_a_turning_body():
    """The body spins 8.6° about the vertical: Lucas–Kanade's one shift per window
    falls short of the turning surface's motion, and least squares matching (affine +
    radiometric) from the previous image, started there, brings the corners closer to
    their true projections (here median 0.43 -> 0.15 px, 90th percentile 0.91 ->
    0.38)."""
    skel, s, balls, theta0, root = _body()
    cam = look_at("near", (0.0, -2.5, 1.0))
    rays = camera_rays(cam)
    theta1 = theta0.copy()
    theta1[skel.dof_index("pelvis_z")] += 0.15
    img0 = _textured(skel, balls, theta0, root, s, cam, rays)
    img1 = _textured(skel, balls, theta1, root, s, cam, rays)
    uv0, bone, q0 = lift_corners(
        skel, balls, theta0, root, s, cam, img0, None, FlowSettings(), rays
    )
    pose1 = forward(skel, theta1[None], root[None], s)
    truth = cam.project(points_world(skel, pose1, bone, q0, np.full(len(bone), -1), s)[0])
    ren1 = render_body(skel, balls, pose1, s, cam, rays)
    seen = visible_points(skel, pose1, cam, ren1, bone, q0, 0.005)[1]
    cfg = FlowSettings()
    lk, ok = follow_corners(img0, img1, uv0, cfg)
    fine, ok_fine = refine_corners(img0, img1, uv0, lk, ok, cfg)
    assert not np.any(ok_fine & ~ok)  # refining only drops corners
    both = ok_fine & seen
    assert both.sum() > 0.5 * seen.sum() > 50
    move = truth[both] - uv0[both]
    assert np.median(np.linalg.norm(move, axis=1)) > 3.0  # a real move
    e_lk = np.linalg.norm(lk[both] - truth[both], axis=1)
    e_fine = np.linalg.norm(fine[both] - truth[both], axis=1)
    assert np.median(e_fine) < 0.7 * np.median(e_lk)
    assert np.percentile(e_fine, 90) < np.percentile(e_lk, 90)
    kept, ok_kept = refine_corners(img0, img1, uv0, lk, ok, FlowSettings(refine_drop=False))
    np.testing.assert_array_equal(ok_kept, ok)  # nothing dropped: the start kept instead
    np.testing.assert_array_equal(kept[ok_fine], fine[ok_fine])
    np.testing.assert_array_equal(kept[ok & ~ok_fine], lk[ok & ~ok_fine])
