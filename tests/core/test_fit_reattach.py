"""A seen forearm and hand keep their place when the hidden upper arm above them is
mirrored (core.fit_reattach, through core.fit_coupling.fill_unobserved)."""

import numpy as np
from scipy.optimize import least_squares

from core import skeleton as sk
from core.fit_coupling import fill_unobserved, limb_dofs
from core.fit_reattach import descendant_dofs
from tests.core.test_fit_mirror import NF, _jumps

SEEN = range(30, 36)


def test_descendants_follow_the_chain():
    skel = sk.make_skeleton()
    below = descendant_dofs(skel)
    k = skel.dof_index("r_shoulder_x")
    names = {skel.dof_names[j] for j in np.flatnonzero(below[k])}
    assert {"r_shoulder_y", "r_elbow_x", "r_wrist_y"} <= names
    assert not any(n.startswith("l_") or "clavicle" in n for n in names)
    assert not below[skel.dof_index("r_wrist_y")].any()  # the chain's end
    assert not below.diagonal().any()


def _fitted_under(skel, s, theta, root, truth, dofs, joints):
    """The seen angles ``dofs`` as a fit under ``theta``'s other angles would give
    them: the joints ``joints`` as near as they reach to the truth's."""
    jt = [skel.joint_names.index(j) for j in joints]
    target = sk.joint_positions(skel, truth, root, s)[jt]

    def res(x):
        q = theta.copy()
        q[dofs] = x
        return (sk.joint_positions(skel, q, root, s)[jt] - target).ravel()

    out = theta.copy()
    out[dofs] = least_squares(res, theta[dofs], bounds=(skel.dof_lo[dofs], skel.dof_hi[dofs])).x
    return out


def test_a_seen_forearm_stays_on_its_points_when_the_upper_arm_is_mirrored(rng):
    skel, s, truth, root = _jumps(rng)
    arm = limb_dofs(skel, "r", "arm")
    seen = [skel.dof_index(n) for n in ("r_elbow_x", "r_elbow_z", "r_wrist_x", "r_wrist_y")]
    hidden = np.zeros(truth.shape, bool)
    hidden[1:, arm] = True
    held = truth.copy()
    held[1:, arm] = truth[0, arm]  # the sequential pass holds the hidden arm
    for f in SEEN:  # the forearm and hand seen: fitted to their points under that hold
        hidden[f, seen] = False
        held[f] = _fitted_under(skel, s, held[f], root[f], truth[f], seen, ["r_wrist", "r_hand"])
    div = np.zeros(NF, bool)
    on, msgs = fill_unobserved(skel, held, root, s, hidden, div, hidden=hidden, anchors=(0,))
    off, _ = fill_unobserved(
        skel, held, root, s, hidden, div, hidden=hidden, anchors=(0,), keep_seen=False
    )
    jt = [skel.joint_names.index(j) for j in ("r_wrist", "r_hand")]

    def err(theta):
        x = sk.joint_positions(skel, theta, root, s)[:, jt]
        t = sk.joint_positions(skel, truth, root, s)[:, jt]
        return np.linalg.norm(x - t, axis=-1)[list(SEEN)]

    e_held, e_on, e_off = err(held), err(on), err(off)
    # mirroring the upper arm swings the seen hand off its place; re-posed, it is back
    # within what the forearm's reach allows from the mirrored elbow
    assert e_off.max() > 0.05 and e_on.max() < 0.25 * e_off.max(), (e_on, e_off)
    assert e_on.max() < max(0.02, 2.0 * e_held.max()), (e_on, e_held)
    # the mirrored angles are the same either way; only the seen ones moved, only there
    hid_arm = [k for k in arm if k not in seen]
    assert np.array_equal(on[:, hid_arm], off[:, hid_arm])
    other = np.setdiff1d(np.arange(NF), list(SEEN))
    assert np.array_equal(on[other], off[other])
    assert any("re-posed" in m for m in msgs)
