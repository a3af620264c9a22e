"""Which shape labels the points in the sequence fit (``segment_initial_radii``)."""

import numpy as np

from core import metaballs as mb
from core import skeleton as sk
from core.fit import FramePoints, SequenceSettings
from core.fit_frame import FrameFitter
from core.fit_init import initialise
from core.landmarks import CLICK_JOINTS
from tests.core._bodyscene import cameras, clicks_of, model_points


def test_a_head_grown_over_the_neck_leaves_the_neck_its_points(rng):
    """make demo's walk: the clicked frame's shape solve stretched the head's lowest
    metaball 0.062 → 0.134 m along the bone, over the neck, and thinned the neck;
    labelled with that shape the head took every neck point (none of 81 stayed the
    neck's) and later tilted onto them.  The initial shape keeps them the neck's,
    whichever shape the fit uses."""
    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    balls = mb.make_metaballs(skel, "complete", s)
    theta, root = np.zeros(skel.n_dof), np.array([0.0, 0.0, 1.0])
    xyz, part = model_points(skel, balls, theta, root, s, rng, per_bone=60)
    neck, head = skel.bone_index("neck"), skel.bone_index("head")
    on_neck = part == neck
    assert on_neck.sum() >= 20
    cams = cameras()
    init = initialise(clicks_of(skel, theta, root, s, cams, CLICK_JOINTS), cams, model="complete")
    # the shape make demo's shape solve gave the neck and head, as ratios to the template
    grown = init.metaballs.radii.copy()
    ratio = {
        neck: [[0.53, 1.0, 0.42], [0.38, 1.08, 0.94], [0.56, 1.04, 0.96]],
        head: [[1.13, 0.93, 2.16], [1.04, 0.97, 1.48], [0.56, 1.06, 0.87]],
    }
    for b, r in ratio.items():
        grown[init.metaballs.bone == b] *= np.array(r)
    frames = [FramePoints(xyz=xyz, sigma=0.001)]
    q = np.concatenate([init.theta, init.root_xyz])
    kept, hidden = {}, {}
    for initial in (True, False):
        fx = FrameFitter(frames, init, SequenceSettings(segment_initial_radii=initial, max_nfev=5))
        fx.radii = grown.copy()  # the shape the fit uses
        _q, _r, ok, got, _labels = fx.one_frame(0, q, np.full(skel.n_dof, 0.1))
        assert ok
        kept[initial] = np.mean(got[on_neck] == neck)
        hidden[initial] = bool(fx.hidden_dofs(xyz, q, 0.04)[skel.dof_bones() == neck].any())
    assert kept[True] > 0.5, kept
    assert kept[False] < 0.2, kept
    # with the grown head's labels the neck has too few points: its angles are held
    assert hidden == {True: False, False: True}
