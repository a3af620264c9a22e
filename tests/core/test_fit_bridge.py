"""Bridging hidden stretches of joint angles (core.fit_bridge)."""

import numpy as np
import pytest

from core.fit_bridge import bridge_hidden, hidden_runs, unobserved


def _held(y, hidden):
    """What the forward fit reports: the last observed value held through each run."""
    out = y.copy()
    for f in range(1, len(y)):
        if hidden[f]:
            out[f] = out[f - 1]
    return out


def test_runs():
    assert hidden_runs(np.array([0, 1, 1, 0, 0, 1], bool)) == [(1, 3), (5, 6)]
    assert hidden_runs(np.zeros(4, bool)) == []


def test_an_angle_is_observed_through_any_part_it_moves():
    # DOFs: 0 trunk, 1 shoulder (child of 0), 2 elbow (child of 1), 3 other arm (of 0)
    parent = np.array([-1, 0, 1, 0])
    hidden = np.array(
        [
            [0, 1, 0, 0],  # upper arm hidden, forearm seen: shoulder observed
            [0, 1, 1, 0],  # the whole arm hidden
            [1, 1, 1, 1],
        ],  # everything hidden
        bool,
    )
    want = np.array([[0, 0, 0, 0], [0, 1, 1, 0], [1, 1, 1, 1]], bool)
    assert np.array_equal(unobserved(hidden, parent), want)


def test_a_smooth_swing_is_recovered_far_better_than_held():
    t = np.arange(60) / 25.0
    truth = 0.6 * np.sin(2 * np.pi * 0.4 * t)[:, None] * np.array([1.0, -0.5])
    hidden = np.zeros(truth.shape, bool)
    hidden[20:32, 0] = True  # 12 frames hidden: the first angle only
    held = np.column_stack([_held(truth[:, 0], hidden[:, 0]), truth[:, 1]])
    out, bridged = bridge_hidden(held, hidden)
    assert np.array_equal(bridged, hidden)
    assert np.array_equal(out[:, 1], truth[:, 1])  # observed angles untouched
    assert np.array_equal(out[~hidden], held[~hidden])
    err_held = np.abs(held[20:32, 0] - truth[20:32, 0]).max()
    err_bridged = np.abs(out[20:32, 0] - truth[20:32, 0]).max()
    assert err_held > 0.3
    assert err_bridged < 0.02 * err_held + 0.005  # cubic Hermite on a smooth curve


def test_straight_lines_without_slopes():
    y = np.linspace(0.0, 1.0, 11)[:, None]
    hidden = np.zeros_like(y, bool)
    hidden[3:8] = True
    out, _ = bridge_hidden(_held(y[:, 0], hidden[:, 0])[:, None], hidden, slopes=False)
    np.testing.assert_allclose(out[:, 0], y[:, 0], atol=1e-12)


def test_open_runs_diverged_ends_and_long_gaps_are_left_held():
    y = np.linspace(0.0, 1.0, 20)[:, None]
    hidden = np.zeros_like(y, bool)
    hidden[:3] = True  # touches the first frame
    hidden[8:11] = True  # bounded by a diverged frame
    hidden[16:] = True  # touches the last frame
    div = np.zeros(20, bool)
    div[11] = True
    held = y.copy()
    out, bridged = bridge_hidden(held, hidden, div)
    assert not bridged.any() and np.array_equal(out, held)
    hidden2 = np.zeros_like(hidden)
    hidden2[5:15] = True
    assert not bridge_hidden(held, hidden2, max_gap=9)[1].any()
    assert bridge_hidden(held, hidden2, max_gap=10)[1][5:15].all()


def test_shape_mismatch_is_an_error():
    with pytest.raises(ValueError, match="differ in shape"):
        bridge_hidden(np.zeros((5, 2)), np.zeros((5, 3), bool))
