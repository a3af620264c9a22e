"""Contours as an observation type of the weighted least-squares fit (issue 7, item 6).

One frame: the contour pairs and their Jacobians, camera selection, the containment
term and the depth holds.  Whole sequences, scenes and the ``core fit`` command with
contours are in ``test_fit_contours_sequence.py``.
"""

import numpy as np
import pytest

from core import metaball_surface as mbs
from core import metaballs as mb
from core import skeleton as sk
from core.camera_selection import Selection, add_wide_views
from core.fit_contours import (
    ContourFrame,
    ContourSettings,
    contour_block,
    match_frame,
)
from core.fitting import FitSettings, Observations, fit
from tests.core._contourscene import _cams, _pose, _silhouettes


@pytest.fixture(scope="module")
def body():
    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    balls = mb.make_metaballs(skel, "simplified", s)
    theta, root = _pose(skel)
    cams = _cams()
    return skel, balls, s, theta, root, cams, _silhouettes(skel, balls, theta, root, s, cams)


@pytest.mark.parametrize("deflated", [False, True])
def test_contour_jacobians_match_finite_differences(body, deflated):
    skel, balls, s, theta, root, cams, observed = body
    if deflated:  # rendered ellipsoids radii · visible_scale, not VISIBLE · radii
        balls = mbs.deflate(skel, balls, s)
    rng = np.random.default_rng(3)
    th = theta + rng.normal(0, 0.03, theta.shape)
    rt = root + np.array([0.01, -0.01, 0.005])
    s1 = s * np.exp(rng.normal(0, 0.03, s.shape))
    b1 = balls.copy(radii=balls.radii * np.exp(rng.normal(0, 0.05, balls.radii.shape)))
    b1.center0 = b1.center0 + rng.normal(0, 0.005, b1.center0.shape)
    pairs, _ = match_frame(skel, b1, th, rt, s1, cams, observed, ContourSettings())
    assert len(pairs) > 200
    r, Jt, Jr, Js, Jrad, Jc = contour_block(skel, b1, th, rt, s1, cams, pairs)
    assert np.abs(r).max() > 0.5  # off the true pose: the residuals are not trivial

    def res(th=th, rt=rt, s=s1, radii=b1.radii, centers=b1.center0):
        b = b1.copy(radii=radii)
        b.center0 = centers
        return contour_block(skel, b, th, rt, s, cams, pairs, shape=False)[0]

    def fd(x, make, cols_k, eps=1e-6):
        cols = []
        for k in cols_k:
            d = np.zeros(x.size)
            d[k] = eps
            cols.append(
                (
                    res(**make((x.ravel() + d).reshape(x.shape)))
                    - res(**make((x.ravel() - d).reshape(x.shape)))
                )
                / (2 * eps)
            )
        return np.stack(cols, axis=1)

    for J, x, make in (
        (Jt, th, lambda v: {"th": v}),
        (Jr, rt, lambda v: {"rt": v}),
        (Js, s1, lambda v: {"s": v}),
        (Jrad, b1.radii, lambda v: {"radii": v}),
        (Jc, b1.center0, lambda v: {"centers": v}),
    ):
        # the columns that any pair depends on, and a few that none does (zero)
        live = np.flatnonzero(np.abs(J).max(axis=0) > 0)
        dead = np.flatnonzero(np.abs(J).max(axis=0) == 0)
        cols_k = np.concatenate([rng.choice(live, min(12, len(live)), replace=False), dead[:2]])
        num = fd(x, make, cols_k)
        scale = np.abs(num).max()
        assert scale > 0
        np.testing.assert_allclose(J[:, cols_k], num, atol=1e-5 * scale)


def test_pose_from_contours_alone_recovers_a_perturbed_pose(body):
    """The weighted LM of core.fitting with contour observations only (no points): five
    limb angles perturbed by 0.12 rad and the root by 2-3 cm come back to the silhouettes'
    pose (every DOF free; the prior, like the sequence fit's, is loose on the perturbed
    angles and tight elsewhere)."""
    skel, balls, s, theta, root, cams, observed = body
    rng = np.random.default_rng(12)
    names = ("l_shoulder_y", "r_shoulder_x", "r_knee_x", "l_hip_x", "l_elbow_x")
    th0 = theta.copy()
    th0[[skel.dof_index(n) for n in names]] += rng.choice([-1, 1], len(names)) * 0.12
    rt0 = root + np.array([0.02, -0.015, 0.01])
    truth = sk.joint_positions(skel, theta, root, s)
    err0 = np.linalg.norm(sk.joint_positions(skel, th0, rt0, s) - truth, axis=1).max()
    cf = ContourFrame(cams, observed, ContourSettings(sigma_px=1.0, huber_px=2.0))
    sig = np.full(skel.n_dof, 0.03)
    sig[[skel.dof_index(n) for n in names]] = 0.5
    obs = Observations(theta_pred=th0, sigma_pred=sig, contours=cf)
    r = fit(
        skel,
        balls,
        obs,
        th0,
        rt0,
        s,
        solve="pose",
        settings=FitSettings(irls_rounds=6, max_nfev=30),
    )
    err = np.linalg.norm(sk.joint_positions(skel, r.theta, r.root_xyz, s) - truth, axis=1)
    assert err0 > 0.05
    assert np.median(err) < 0.005 and err.max() < 0.02, (err0, np.median(err), err.max())
    assert np.all(np.isfinite(r.theta_sigma))
    # every part recorded which cameras it used (visibility >= 0.2)
    used = cf.cameras_used(skel)
    assert used["pelvis"] and set(used["pelvis"]) <= {c.name for c in cams}


def test_skipped_parts_get_no_contour_pairs(body):
    skel, balls, s, theta, root, cams, observed = body
    head, neck = skel.bone_index("head"), skel.bone_index("neck")
    full, _ = match_frame(skel, balls, theta, root, s, cams, observed, ContourSettings())
    assert (full.bone == head).sum() > 20
    skip, sel = match_frame(
        skel, balls, theta, root, s, cams, observed, ContourSettings(skip_parts=("head", "neck"))
    )
    assert not np.isin(skip.bone, [head, neck]).any()
    assert not sel.use[[head, neck]].any()
    others = ~np.isin(full.bone, [head, neck])
    assert len(skip) >= 0.9 * others.sum()  # the other parts keep their pairs


def _selection(body, rate, cfg):
    """The cameras each part of the fixture's body selects with settings ``cfg``."""
    skel, balls, s, theta, root, cams, observed = body
    return match_frame(skel, balls, theta, root, s, cams, observed, cfg, theta_rate=rate)[1]


def test_selection_by_visibility_alone_ignores_the_predicted_motion(body):
    skel = body[0]
    rate = np.zeros(skel.n_dof)
    rate[skel.dof_index("l_hip_x")] = 0.2
    by_motion = _selection(body, rate, ContourSettings())
    by_vis = _selection(body, rate, ContourSettings(rank_motion=False))
    visible = np.nan_to_num(by_vis.visibility, nan=0.0) >= 0.2
    np.testing.assert_array_equal(by_vis.use, visible)
    assert np.all(by_motion.use <= by_vis.use)
    assert np.any(by_motion.observability > 0)


def test_views_left_out_paired_with_a_larger_sigma(body):
    """unselected_sigma_scale: the views the selection leaves out are paired too, with
    their σ times the scale.  The selection itself (what the frame records) is
    unchanged; a contour point still pairs with the nearest rim point, now among more
    parts, so the selected views keep the hard selection's pairs but for those an
    extra part's rim is nearer to."""
    skel, balls, s, theta, root, cams, observed = body
    rate = np.zeros(skel.n_dof)
    rate[skel.dof_index("l_hip_x")] = 0.2
    paper = ContourSettings(unselected_sigma_scale=None)
    hard, sel = match_frame(skel, balls, theta, root, s, cams, observed, paper, theta_rate=rate)
    cfg = ContourSettings(unselected_sigma_scale=3.0)
    soft, sel2 = match_frame(skel, balls, theta, root, s, cams, observed, cfg, theta_rate=rate)
    np.testing.assert_array_equal(sel.use, sel2.use)
    assert np.all(hard.sigma_scale == 1.0)
    chosen = sel.use[soft.bone, soft.camera]
    assert np.all(soft.sigma_scale[chosen] == 1.0) and np.all(soft.sigma_scale[~chosen] == 3.0)
    assert (~chosen).sum() > 50  # left-out views do show those parts' outlines

    def key(p, k):  # (camera, contour point, metaball) of the pairs k
        return set(zip(p.camera[k], *p.z[k].T, p.ellipsoid[k], strict=True))

    kept = key(soft, chosen)
    assert kept <= key(hard, slice(None)) and len(kept) >= 0.95 * len(hard)
    # each pair's weight: Huber of its residual in its own σ units, over its σ
    frame = ContourFrame(cams, observed, cfg, theta_rate=rate)
    frame.freeze(skel, balls, theta, root, s)
    r = contour_block(skel, balls, theta, root, s, cams, frame.pairs, shape=False)[0]
    sig = cfg.sigma_px * frame.pairs.sigma_scale
    a = np.abs(r) / frame.pairs.sigma_scale
    want = np.where(a <= cfg.huber_px, 1.0, np.sqrt(cfg.huber_px / np.maximum(a, 1e-300))) / sig
    np.testing.assert_allclose(frame.weights, want, rtol=1e-12)
    assert (frame.weights[frame.pairs.sigma_scale > 1] < 1 / cfg.sigma_px).all()


def test_wide_view_joins_a_part_whose_ranked_views_look_alike(body):
    """wide_view_deg: the motion ranking keeps the views that see a limb swing; a part
    left with views within depth_spread_deg of each other also gets, of the visible
    cameras at least wide_view_deg across them, the best ranked (here the cameras' lines
    of sight cross at 45°, 90° and 45°)."""
    skel, balls, s, theta, root, cams, observed = body
    rate = np.zeros(skel.n_dof)
    rate[skel.dof_index("l_shoulder_x")] = 0.2
    rate[skel.dof_index("r_elbow_x")] = 0.2
    ranked = _selection(body, rate, ContourSettings(wide_view_deg=None))  # the paper's
    wide = _selection(body, rate, ContourSettings(wide_view_deg=40.0, wide_view_outline=0))
    visible = np.nan_to_num(ranked.visibility, nan=0.0) >= 0.2
    assert np.all(ranked.use <= wide.use) and np.all(wide.use <= visible)
    added = wide.use & ~ranked.use
    assert added.any()
    assert np.all(added.sum(axis=1) <= 1)  # one camera at most ...
    eyes = np.array([c.center for c in cams])
    pose = sk.forward(skel, theta[None], root[None], s)
    centres = mb.world_frames(skel, pose, balls, s)[1][0]  # (M, 3) metaball centres

    def line(u, v):  # angle between two lines of sight, degrees
        return np.degrees(np.arccos(min(1.0, abs(u @ v))))

    for p in np.flatnonzero(ranked.use.any(axis=1)):
        ray = centres[balls.bone == p].mean(axis=0) - eyes
        ray /= np.linalg.norm(ray, axis=1, keepdims=True)
        kept = np.flatnonzero(ranked.use[p])
        spread = max(line(ray[a], ray[b]) for a in kept for b in kept)
        across = {
            c: min(line(ray[a], ray[c]) for a in kept)
            for c in np.flatnonzero(visible[p] & ~ranked.use[p])
        }
        wide_ones = [(ranked.observability[p, c], a, c) for c, a in across.items() if a >= 40.0]
        if spread <= 40.0 and wide_ones:
            b = np.flatnonzero(added[p])  # ... to a part whose kept views look alike: of
            assert len(b) == 1 and b[0] == max(wide_ones)[2]  # those across, the best ranked
        else:
            assert not added[p].any()
    # no camera far enough across: the paper's selection alone
    far = _selection(body, rate, ContourSettings(wide_view_deg=150.0, wide_view_outline=0))
    np.testing.assert_array_equal(far.use, ranked.use)


def test_wide_view_counts_only_views_that_show_the_parts_outline():
    """A kept view in which the part shows no outline (an arm in front of the trunk) does
    not count: two kept views 90° apart, one of them without outline, leave the part
    one-sided, and the camera across that shows its outline joins; one without outline
    does not."""
    eyes = np.array([[4.0, 0.0, 1.0], [0.0, -4.0, 1.0], [0.0, 0.0, 5.0]])  # along x, y, z

    def added(outline):
        use = np.array([[True, True, False]])
        sel = Selection(use, np.ones((1, 3)), np.array([[5.0, 3.0, 1.0]]), np.zeros((1, 3), int))
        add_wide_views(sel, eyes, np.array([[0.0, 0.0, 1.0]]), 40.0, 60.0, 0.2, None, [outline], 4)
        return sel.use[0, 2]

    assert not added([20, 20, 20])  # two views 90° apart: not one-sided
    assert added([0, 20, 20])  # the first shows no outline: one-sided, the third joins
    assert not added([0, 20, 2])  # ... unless the third shows none either
    assert not added([0, 0, 20])  # neither kept view shows it: judged on both, 90° apart


def test_one_view_does_not_unhide_a_part_beside_points(body):
    """part_counts(min_views=2): a part's contour pairs count only when two or more
    cameras give it 10 or more pairs each (one view's contours leave its depth free)."""
    skel, balls, s, theta, root, cams, observed = body
    P = len(skel.bone_names)
    cf = ContourFrame(cams, observed, ContourSettings())
    cf.freeze(skel, balls, theta, root, s)
    one, two = cf.part_counts(P), cf.part_counts(P, min_views=2)
    per = np.zeros((P, len(cams)), int)
    np.add.at(per, (cf.pairs.bone, cf.pairs.camera), 1)
    multi = (per >= 10).sum(axis=1) >= 2
    np.testing.assert_array_equal(two, np.where(multi, one, 0))
    assert multi.sum() >= 5 and two.sum() > 0.5 * one.sum()
    # only the first camera's contours: every part is seen by one view
    only = ContourFrame(cams, [observed[0], [], []], ContourSettings())
    only.freeze(skel, balls, theta, root, s)
    assert only.part_counts(P).sum() > 100
    assert not only.part_counts(P, min_views=2).any()


def test_containment_jacobians_match_finite_differences(body):
    """The containment rows (robust above the Huber knee) against central differences,
    at a pose with the right arm swung out of every camera's silhouette."""
    skel, balls, s, theta, root, cams, observed = body
    th = theta.copy()
    th[skel.dof_index("r_shoulder_y")] += 0.7
    th[skel.dof_index("l_hip_x")] -= 0.3
    rt = root + np.array([0.01, -0.01, 0.005])
    cf = ContourFrame(cams, observed, ContourSettings(containment_px=2.0, huber_px=4.0))
    r, Jt, Jr = cf.containment_block(skel, balls, th, rt, s)
    assert (r > 0).sum() > 20 and r.max() * 2.0 > 3 * 4.0  # some beyond the knee
    live = np.flatnonzero(np.abs(Jt).max(axis=0) > 0)
    assert skel.dof_index("r_shoulder_y") in live
    eps = 1e-6
    for k in live:
        d = np.zeros_like(th)
        d[k] = eps
        num = (
            cf.containment_block(skel, balls, th + d, rt, s)[0]
            - cf.containment_block(skel, balls, th - d, rt, s)[0]
        ) / (2 * eps)
        # the distance field is bilinear: compare where no sample crossed a pixel edge
        np.testing.assert_allclose(
            np.median(np.abs(Jt[:, k] - num)), 0.0, atol=1e-3 * max(np.abs(num).max(), 1e-9)
        )
    for k in range(3):
        d = np.zeros(3)
        d[k] = eps
        num = (
            cf.containment_block(skel, balls, th, rt + d, s)[0]
            - cf.containment_block(skel, balls, th, rt - d, s)[0]
        ) / (2 * eps)
        np.testing.assert_allclose(
            np.median(np.abs(Jr[:, k] - num)), 0.0, atol=1e-3 * np.abs(num).max()
        )
    # off: no rows; at the silhouettes' own pose nothing is outside
    assert (
        ContourFrame(cams, observed, ContourSettings(containment_px=0.0)).containment_block(
            skel, balls, th, rt, s
        )
        is None
    )
    r0 = cf.containment_block(skel, balls, theta, root, s)[0]
    assert np.all(r0 == 0)
    # the parts it holds: the same rows as the whole body's, restricted to them
    from core.contour_obs import containment_observations, silhouette_field

    fields = [silhouette_field(cons, cam.size) for cons, cam in zip(observed, cams, strict=True)]
    full = containment_observations(skel, th, rt, s, balls, cams, fields, tol_px=2.0)
    arm = np.isin(
        np.arange(len(skel.bone_names)),
        [skel.bone_index(b) for b in ("r_shoulder", "r_elbow", "r_wrist")],
    )
    cf.containment_parts = arm
    ra, Jta, _ = cf.containment_block(skel, balls, th, rt, s)
    sel = arm[full.part]
    assert 0 < len(ra) == sel.sum() < len(full.residual)
    np.testing.assert_allclose(
        ra * 2.0,
        np.where(
            full.residual[sel] > 4.0,
            np.sqrt(np.maximum(8.0 * full.residual[sel] - 16.0, 0.0)),
            full.residual[sel],
        ),
    )
    cf.containment_parts = np.zeros(len(skel.bone_names), bool)
    assert cf.containment_block(skel, balls, th, rt, s) is None


def test_containment_brings_back_an_arm_beyond_the_pairing_reach(body):
    """An arm swung 1.2 rad out of the silhouettes is beyond the contour pairing's reach
    (12 px): the contours alone leave it out there; with the containment term the
    weighted LM pulls it back inside every camera's foreground.  The paper's selection
    (the left-out views unpaired): the views the selection leaves out here reach the
    arm and bring it back by themselves (wrist 58 mm off without the term)."""
    skel, balls, s, theta, root, cams, observed = body
    th0 = theta.copy()
    arm = [skel.dof_index(n) for n in ("r_shoulder_x", "r_shoulder_y", "r_shoulder_z", "r_elbow_x")]
    th0[skel.dof_index("r_shoulder_y")] += 1.2
    truth = sk.joint_positions(skel, theta, root, s)
    wrist = skel.joint_index("r_wrist")
    sig = np.full(skel.n_dof, 0.02)
    sig[arm] = 1.0
    err = {}
    for px in (0.0, 3.0):
        cfg = ContourSettings(containment_px=px, unselected_sigma_scale=None)
        cf = ContourFrame(cams, observed, cfg)
        obs = Observations(theta_pred=th0, sigma_pred=sig, contours=cf)
        r = fit(
            skel,
            balls,
            obs,
            th0,
            root,
            s,
            solve="pose",
            settings=FitSettings(irls_rounds=4, max_nfev=40),
        )
        err[px] = np.linalg.norm(
            sk.joint_positions(skel, r.theta, r.root_xyz, s)[wrist] - truth[wrist]
        )
        if px:
            assert np.all(cf.containment_block(skel, balls, r.theta, r.root_xyz, s)[0] < 1.0)
    assert err[0.0] > 0.25, err
    assert err[3.0] < 0.08 and err[3.0] < 0.25 * err[0.0], err


def test_containment_holds_the_untextured_parts_in_frames_with_points_only():
    from core.fit_contours import containment_parts

    counts = np.array([0, 3, 8, 40])
    cfg = ContourSettings(containment_px=3.0, containment_textured=False)
    np.testing.assert_array_equal(
        containment_parts(counts, True, 8, cfg), [True, True, False, False]
    )
    np.testing.assert_array_equal(containment_parts(counts, False, 8, cfg), [False] * 4)
    every = ContourSettings(containment_px=3.0, containment_textured=True)
    assert containment_parts(counts, True, 8, every).all()
    assert not containment_parts(counts, False, 8, every).any()


def test_one_view_depth_holds_keep_the_arm_on_its_side_of_the_image_plane(body):
    """Contours of one camera only (cam01, in front of the subject): an arm swung 0.3 rad
    away from the camera and its mirror image, swung 0.3 rad towards it, draw almost the
    same outline.  Started from the mirror (a prediction that overshot), the fit without
    depth holds stays there; holding the elbow and wrist along cam01's rays at the
    previous frame's depth (the arm swung away) brings it back to the true side, and
    still lets it follow a swing in the image (0.2 rad of abduction)."""
    from core.fit_depth import depth_holds

    skel, balls, s, theta, root, cams, observed = body
    swing, abduct = skel.dof_index("r_shoulder_x"), skel.dof_index("r_shoulder_y")
    prev = theta.copy()
    prev[swing] = 0.3  # the previous frame: swung away from cam01
    truth_th = prev.copy()
    truth_th[abduct] -= 0.2  # this frame: abducted less, in cam01's image plane
    start = truth_th.copy()
    start[swing] = -0.3  # the mirror image, towards cam01
    one_view = [_silhouettes(skel, balls, truth_th, root, s, cams)[0], [], []]
    sig = np.full(skel.n_dof, 0.03)
    sig[[swing, abduct, skel.dof_index("r_elbow_x")]] = 0.5
    B = len(skel.bone_names)
    view = np.full(B, -1)
    view[[skel.bone_index("r_shoulder"), skel.bone_index("r_elbow")]] = 0
    joints = [skel.joint_index("r_elbow"), skel.joint_index("r_wrist")]
    truth = sk.joint_positions(skel, truth_th, root, s)[joints]
    err, rms = {}, {}
    for held in (False, True):
        cf = ContourFrame(cams, one_view, ContourSettings(sigma_px=1.0, huber_px=2.0))
        obs = Observations(theta_pred=start, sigma_pred=sig, contours=cf)
        if held:
            obs.depth = depth_holds(skel, prev, root, s, view, cams, np.ones(B, bool), 0.03)
            assert len(obs.depth) == 2  # the elbow and the wrist
        r = fit(
            skel,
            balls,
            obs,
            start,
            root,
            s,
            solve="pose",
            settings=FitSettings(irls_rounds=6, max_nfev=30),
        )
        err[held] = np.linalg.norm(
            sk.joint_positions(skel, r.theta, r.root_xyz, s)[joints] - truth, axis=1
        ).max()
        rms[held] = cf.stats(skel, balls, r.theta, r.root_xyz, s)["rms_px"]
    assert err[False] > 0.08, err  # stayed on the mirror side
    assert err[True] < 0.015, err
    assert rms[False] < 2.0 and rms[True] < 2.0, rms  # both explain the one view


def test_frame_depth_holds_cover_the_single_view_parts_that_are_not_hidden(body):
    """Only cam01's contours: every part with pairs is seen by one view and its joints
    are held along cam01's rays, except those of hidden parts; with every camera's
    contours (the parts seen by two or more views) there are fewer holds."""
    from core.fit_depth import frame_depth_holds

    skel, balls, s, theta, root, cams, observed = body
    hidden = np.zeros(skel.n_dof, bool)
    hidden[[skel.dof_index(d) for d in skel.dof_names if d.startswith("r_shoulder_")]] = True
    one = ContourFrame(cams, [observed[0], [], []], ContourSettings())
    one.freeze(skel, balls, theta, root, s)
    holds = frame_depth_holds(skel, one, hidden, theta, root, s)
    carried = {skel.bone_names[skel.joint_bone[j]] for j in holds.joint}
    seen = {
        skel.bone_names[b] for b in np.unique(one.pairs.bone) if np.sum(one.pairs.bone == b) >= 10
    }
    assert carried == seen - {"r_shoulder"} and "r_elbow" in carried
    x = sk.joint_positions(skel, theta, root, s)[holds.joint]
    np.testing.assert_allclose(np.cross(holds.direction, x - cams[0].center), 0.0, atol=1e-12)
    every = ContourFrame(cams, observed, ContourSettings())
    every.freeze(skel, balls, theta, root, s)
    assert len(frame_depth_holds(skel, every, hidden, theta, root, s)) < len(holds)
    off = ContourFrame(cams, observed, ContourSettings(depth_sigma_m=None))
    off.freeze(skel, balls, theta, root, s)
    assert frame_depth_holds(skel, off, hidden, theta, root, s) is None
