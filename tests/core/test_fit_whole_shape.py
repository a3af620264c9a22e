"""The whole-body shape written after the motion (core.fit_whole_shape): which frames,
which parts, and the rendered ellipsoids following the blend."""

from __future__ import annotations

import numpy as np

from core import metaball_surface as mbs
from core import metaballs as mb
from core import skeleton as sk
from core.fit_bridge import unobserved
from core.fit_whole_shape import blend_scale, measured_parts, shape_fit_frames


def test_frames_spread_over_the_take_with_silhouettes_else_near_the_click():
    good = np.array([0, 1, 2, 3, 5, 8, 9, 10, 11, 12, 20, 30, 31, 40])
    assert shape_fit_frames(good, 9, near=3, spread=0).tolist() == [8, 9, 10]
    assert shape_fit_frames(good, 9, near=3, spread=5).tolist() == [0, 3, 9, 20, 40]
    assert shape_fit_frames(good[:3], 0, near=3, spread=5).tolist() == [0, 1, 2]
    assert shape_fit_frames(np.array([], int), 0, near=3, spread=5).tolist() == []


def test_a_part_posed_by_inference_is_not_measured():
    """A hidden forearm and hand (mirrored or held) leave the forearm and hand
    unmeasured, not the upper arm; a hidden pelvis whose children are seen is placed by
    them; ``always`` overrides (the head, whose contours the pose fit skips)."""
    skel = sk.make_skeleton()
    hid = np.zeros((3, skel.n_dof), bool)
    arm = [skel.dof_index(d) for d in ("r_elbow_x", "r_elbow_z", "r_wrist_x", "r_wrist_y")]
    hid[1, arm] = True
    hid[:, [skel.dof_index(d) for d in ("pelvis_x", "pelvis_y", "pelvis_z")]] = True
    hid[:, [skel.dof_index(d) for d in ("head_x", "head_y")]] = True
    parts = measured_parts(skel, unobserved(hid, skel.dof_parent), always=("head",))
    names = list(skel.bone_names)
    unmeasured = {f: sorted(names[b] for b in np.flatnonzero(~parts[f])) for f in range(3)}
    assert unmeasured == {0: [], 1: ["r_elbow", "r_wrist"], 2: []}
    parts = measured_parts(skel, unobserved(hid, skel.dof_parent))
    assert not parts[:, names.index("head")].any()


def test_blend_scale_renders_the_blended_surface():
    """The ellipsoids ``radii · blend_scale`` follow Σ f = 0.5: points on them lie on
    the blend (the lone ellipsoids ``radii · VISIBLE`` lie inside it where metaballs
    overlap)."""
    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    balls = mb.make_metaballs(skel, "simplified", s)
    theta = np.zeros((2, skel.n_dof))
    theta[1, skel.dof_index("l_knee_x")] = 0.8
    root = np.array([[0.0, 0.0, 1.0], [0.1, 0.0, 1.0]])
    scale = blend_scale(skel, balls, s, theta, root)
    assert scale.shape == balls.radii.shape
    assert np.all(scale >= mb.VISIBLE - 1e-12) and np.all(scale <= 2 * mb.VISIBLE + 1e-12)
    pose = sk.forward(skel, theta[:1], root[:1], s)
    Rw, cw = mb.world_frames(skel, pose, balls, s)
    u = mbs.fibonacci_sphere(32)

    def level(axes):
        """Mean |ln Σf − ln 0.5| on the union of the ellipsoids ``axes`` (M, 3): points
        spread over each, those inside another left out."""
        x = cw[0][:, None] + np.einsum("mij,mpj->mpi", Rw[0], u[None] * axes[:, None])
        x = x.reshape(-1, 3)
        y = mb.local_coords(x, Rw[0], cw[0])
        inside = np.sum((y / axes[None]) ** 2, axis=-1) < 1.0 - 1e-9
        inside[np.arange(len(x)), np.repeat(np.arange(len(axes)), len(u))] = False
        F = mb.field(x[~inside.any(axis=1)], Rw[0], cw[0], balls.radii)[0]
        return np.mean(np.abs(np.log(F / 0.5)))

    # seeded template: 0.17 against 0.82 (the lone ellipsoids lie deep inside the blend)
    assert level(balls.radii * scale) < 0.3 * level(balls.radii * mb.VISIBLE)
