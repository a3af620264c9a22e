"""Contour tracking inside the EKF, on silhouettes the model itself produces."""

import numpy as np
import pytest

from core.contour_obs import body_ellipsoids
from core.contour_track import ContourTrackSettings, fit_shape_to_contours, track_contours
from core.contours import occluding_contours
from core.fit_contours import ContourSettings
from core.metaballs import make_metaballs
from core.model_render import render_parts
from core.skeleton import joint_positions, make_skeleton
from tests.core.test_contour_obs import _look_at


@pytest.fixture(scope="module")
def rig():
    skel = make_skeleton()
    balls = make_metaballs(skel)
    s = np.ones(skel.n_groups)
    target = np.array([0.0, 0.0, 1.0])
    cams = [
        _look_at(target + d, target)
        for d in (
            np.array([0.0, -4.0, 0.0]),
            np.array([4.0, 0.0, 0.0]),
            np.array([-2.8, -2.8, 0.0]),
        )
    ]
    return skel, balls, s, cams


def _contours(skel, theta, root, s, balls, cams):
    out = []
    for cam in cams:
        c, a, r, p = body_ellipsoids(skel, theta, root, s, balls)
        out.append(occluding_contours(render_parts(cam, c, a, r, p).mask, spacing=1.5))
    return out


def _swing(skel, F=8):
    """Arms and legs swinging, the body walking forward (smooth, ~3 cm/frame)."""
    theta = np.zeros((F, skel.n_dof))
    t = np.arange(F)
    for name, amp, base in (
        ("l_shoulder_x", 0.35, 0.0),
        ("r_shoulder_x", -0.35, 0.0),
        ("l_shoulder_y", 0.0, -0.5),
        ("r_shoulder_y", 0.0, 0.5),
        ("l_hip_x", -0.3, 0.0),
        ("r_hip_x", 0.3, 0.0),
        ("l_elbow_x", 0.2, -0.5),
        ("r_knee_x", 0.2, 0.3),
    ):
        theta[:, skel.dof_index(name)] = base + amp * np.sin(t / 4.0)
    root = np.stack([np.zeros(F), -0.03 * t, np.full(F, 1.0)], axis=1)
    return theta, root


def test_shape_from_silhouettes_recovers_radii(rig):
    skel, balls, s, cams = rig
    theta, root = _swing(skel, 1)
    truth = balls.copy(radii=balls.radii * np.where(np.arange(len(balls)) % 2, 1.12, 0.9)[:, None])
    observed = _contours(skel, theta[0], root[0], s, truth, cams)
    start_err = np.abs(balls.radii - truth.radii).mean()
    fitted, th, rt, rms = fit_shape_to_contours(
        skel, s, balls, theta[0], root[0], cams, observed, ContourTrackSettings(q_sigma_theta=0.01)
    )
    assert rms < 1.0
    # radii along bones and hidden ones are weakly observed: the error falls, not to zero
    assert np.abs(fitted.radii - truth.radii).mean() < 0.75 * start_err

    def iou(body):
        ious = []
        for cam in cams:
            a = render_parts(cam, *body_ellipsoids(skel, th, rt, s, body)).mask
            b = render_parts(cam, *body_ellipsoids(skel, theta[0], root[0], s, truth)).mask
            ious.append((a & b).sum() / (a | b).sum())
        return np.mean(ious)

    # silhouettes agree far better than the template's (0.89 here)
    assert iou(fitted) > 0.95 and iou(fitted) > iou(balls) + 0.05


def test_shape_from_silhouettes_moves_centres_off_the_bone_axis(rig):
    """Head and chest lie 3 cm off their bones' axes: with free centres (the trunk's and
    legs', as the fit frees them) the fit moves them there; the arms' stay."""
    skel, balls, s, cams = rig
    theta, root = _swing(skel, 1)
    names = np.array(skel.bone_names)[balls.bone]
    moved = np.flatnonzero(np.isin(names, ["chest", "head"]))
    centres = balls.center0.copy()
    centres[moved] += [0.0, 0.03, 0.0]
    truth = balls.with_parts(centres, balls.radii)
    observed = _contours(skel, theta[0], root[0], s, truth, cams)
    tight = ContourTrackSettings(q_sigma_theta=0.01, q_sigma_root=0.002)
    held, *_ = fit_shape_to_contours(skel, s, balls, theta[0], root[0], cams, observed, tight)
    cfg = ContourSettings()
    sigma = np.where(np.isin(names, cfg.shape_center_parts), cfg.shape_center_sigma_m, np.nan)
    free, th, rt, rms = fit_shape_to_contours(
        skel, s, balls, theta[0], root[0], cams, observed, tight, center_prior_m=sigma
    )
    assert np.array_equal(held.center0, balls.center0)
    err = np.linalg.norm(free.center0[moved] - centres[moved], axis=1)
    assert err.mean() < 0.5 * 0.03, err  # 3 cm off before
    arms = ~np.isin(names, cfg.shape_center_parts)
    assert arms.sum() > 10 and np.array_equal(free.center0[arms], balls.center0[arms])
    assert np.linalg.norm(rt - root[0]) < 0.005 and rms < 1.0

    def iou(body, th_, rt_):
        a = [render_parts(cam, *body_ellipsoids(skel, th_, rt_, s, body)).mask for cam in cams]
        b = [
            render_parts(cam, *body_ellipsoids(skel, theta[0], root[0], s, truth)).mask
            for cam in cams
        ]
        return np.mean([(x & y).sum() / (x | y).sum() for x, y in zip(a, b, strict=True)])

    assert iou(free, th, rt) > iou(held, theta[0], root[0]) + 0.005


def test_held_parts_keep_their_template_shape(rig):
    """The parts ``ContourSettings.shape_held_parts`` names (the head) keep the
    template's radii and centres while the rest of the body takes the silhouettes'."""
    from core.fit_silhouette_shape import center_sigma, radius_sigma

    skel, balls, s, cams = rig
    theta, root = _swing(skel, 1)
    truth = balls.copy(radii=balls.radii * np.where(np.arange(len(balls)) % 2, 1.12, 0.9)[:, None])
    observed = _contours(skel, theta[0], root[0], s, truth, cams)
    names = np.array(skel.bone_names)[balls.bone]
    head = names == "head"
    tight = ContourTrackSettings(q_sigma_theta=0.01, q_sigma_root=0.002)
    fitted = {}
    for held in ((), ("head",)):
        cfg = ContourSettings(shape_held_parts=held)
        sig_r, sig_c = radius_sigma(skel, balls, cfg), center_sigma(skel, balls, cfg)
        assert np.all(sig_r[head] == (0.002 if held else 0.02))
        assert np.all(np.isnan(sig_c[head]) == bool(held))
        fitted[held], *_ = fit_shape_to_contours(
            skel, s, balls, theta[0], root[0], cams, observed, tight, sig_r, center_prior_m=sig_c
        )
    moved = {k: np.abs(v.radii - balls.radii).max(axis=1) for k, v in fitted.items()}
    # free, the head takes its silhouette's size (22 mm here); held, a third of that
    assert moved[()][head].max() > 0.015
    assert moved[("head",)][head].max() < min(0.01, 0.35 * moved[()][head].max())
    assert np.array_equal(fitted[("head",)].center0[head], balls.center0[head])
    # the rest of the body is shaped as before
    rest = ~head
    err = {k: np.abs(v.radii[rest] - truth.radii[rest]).mean() for k, v in fitted.items()}
    assert err[("head",)] < 1.1 * err[()], err


def test_containment_pulls_a_metaball_far_out_of_the_silhouettes_back_in(rig):
    """A head four times too wide stands out of the outlines beyond what the contour
    pairing reaches: the containment (``fields``) brings it back, the pairing alone
    does not."""
    from core.contour_obs import silhouette_field

    skel, balls, s, cams = rig
    theta, root = _swing(skel, 1)
    observed = _contours(skel, theta[0], root[0], s, balls, cams)
    fields = [silhouette_field(c, cam.size) for c, cam in zip(observed, cams, strict=True)]
    head = np.flatnonzero(np.array(skel.bone_names)[balls.bone] == "head")
    start = balls.radii.copy()
    start[head, 0] *= 4.0  # 41 cm too wide
    tight = ContourTrackSettings(q_sigma_theta=0.01, q_sigma_root=0.002)
    err, iou = {}, {}
    for name, f in (("pairs", None), ("contained", fields)):
        fit, th, rt, _ = fit_shape_to_contours(
            skel, s, balls.copy(radii=start), theta[0], root[0], cams, observed, tight, fields=f
        )
        err[name] = np.abs(fit.radii[head] - balls.radii[head]).max()
        a = [render_parts(c, *body_ellipsoids(skel, th, rt, s, fit)).mask for c in cams]
        truth = body_ellipsoids(skel, theta[0], root[0], s, balls)
        b = [render_parts(c, *truth).mask for c in cams]
        iou[name] = np.mean([(x & y).sum() / (x | y).sum() for x, y in zip(a, b, strict=True)])
    assert err["contained"] < 0.015 and err["contained"] < 0.5 * err["pairs"], err
    assert iou["contained"] > iou["pairs"], iou


def test_tracking_follows_the_motion_with_and_without_selection(rig):
    skel, balls, s, cams = rig
    theta, root = _swing(skel)
    contours = [_contours(skel, theta[f], root[f], s, balls, cams) for f in range(len(theta))]
    truth = joint_positions(skel, theta, root, s)
    errs = {}
    for select in (True, False):
        out = track_contours(
            skel, s, balls, theta[0], root[0], cams, contours, ContourTrackSettings(select=select)
        )
        assert all(t.updated for t in out)
        th = np.array([t.theta for t in out])
        rt = np.array([t.root for t in out])
        err = np.linalg.norm(joint_positions(skel, th, rt, s) - truth, axis=2)
        errs[select] = err
        # a still model would be off by the motion itself (several cm by the end)
        assert np.median(err[-1]) < 0.015, (select, np.median(err, axis=1))
    moved = np.linalg.norm(truth[-1] - truth[0], axis=1)
    assert np.median(moved) > 0.15
    # camera use is recorded per part and frame
    assert out[3].use.shape == (len(skel.bone_names), len(cams))


def test_a_frame_without_contours_coasts_on_the_prediction(rig):
    skel, balls, s, cams = rig
    theta, root = _swing(skel, 6)
    contours = [_contours(skel, theta[f], root[f], s, balls, cams) for f in range(6)]
    contours[3] = [[] for _ in cams]  # the person left every image for one frame
    out = track_contours(skel, s, balls, theta[0], root[0], cams, contours)
    assert [t.updated for t in out] == [True, True, True, False, True, True]
    assert np.all(np.isfinite(out[3].theta))
    err = np.linalg.norm(
        joint_positions(skel, out[5].theta, out[5].root, s)
        - joint_positions(skel, theta[5], root[5], s),
        axis=1,
    )
    assert np.median(err) < 0.015  # recovered after the gap


def test_contours_restore_a_part_the_points_did_not_see(rig):
    """A fitted state whose left arm was held at a wrong angle (σ unknown: no points):
    fusing the silhouettes moves that arm back; well-determined DOFs stay put."""
    from core.contour_track import refine_state_with_contours
    from core.state import FitState, Quality

    skel, balls, s, cams = rig
    theta, root = _swing(skel, 3)
    contours = [_contours(skel, theta[f], root[f], s, balls, cams) for f in range(3)]
    wrong = theta.copy()
    arm = [skel.dof_index(n) for n in ("l_shoulder_x", "l_shoulder_y")]
    wrong[:, arm] += 0.15
    q = Quality.empty(3, skel.n_dof)
    q.theta_sigma[:] = 0.002  # the points pinned every DOF ...
    q.theta_sigma[:, arm] = np.nan  # ... except the unseen arm's
    state = FitState(skel, s, balls, root.copy(), wrong, q)
    out = refine_state_with_contours(state, cams, contours)
    err = lambda th: np.linalg.norm(  # noqa: E731
        joint_positions(skel, th, root, s)[:, skel.joint_index("l_wrist")]
        - joint_positions(skel, theta, root, s)[:, skel.joint_index("l_wrist")],
        axis=1,
    )
    assert err(wrong).min() > 0.05
    assert err(out.theta).max() < 0.015
    # the pinned DOFs move at most about two σ floors (0.02 rad: point-fit σ are optimistic)
    others = np.setdiff1d(np.arange(skel.n_dof), arm)
    assert np.abs(out.theta[:, others] - wrong[:, others]).max() < 0.05
    assert out.quality.cameras[0]["l_shoulder"]  # cameras used by the part are recorded
