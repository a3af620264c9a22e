"""Held angles smoothed over time where nothing observes a part (core.fit_smooth)."""

import numpy as np

from core.fit_smooth import smooth_held


def test_one_frame_excursions_of_a_held_angle_are_dropped_and_its_drift_kept(rng):
    nf = 40
    drift = np.linspace(0.2, 0.6, nf)  # a slow drift, monotonic: a median keeps it
    theta = np.column_stack([drift, drift.copy(), np.full(nf, 0.3)])
    spikes = [5, 17, 18, 30]  # one- and two-frame excursions, as on jumps_line3's leg
    theta[spikes, 1] += rng.choice([-1, 1], len(spikes)) * 0.12
    held = np.zeros(theta.shape, bool)
    held[:, 1:] = True  # column 0 is observed: untouched
    out, smoothed = smooth_held(theta, held)
    assert np.array_equal(out[:, 0], theta[:, 0]) and not smoothed[:, 0].any()
    assert np.allclose(out[:, 1], drift, atol=0.011), np.abs(out[:, 1] - drift).max()
    assert np.array_equal(out[:, 2], theta[:, 2])  # a held constant stays
    assert set(np.flatnonzero(smoothed[:, 1])) >= set(spikes)


def test_a_diverged_frame_breaks_the_stretch_and_is_left_alone():
    theta = np.zeros((12, 1))
    theta[6:, 0] = 1.0  # the held value steps where the frame between diverged
    theta[5, 0] = 9.0
    div = np.zeros(12, bool)
    div[5] = True
    out, smoothed = smooth_held(theta, np.ones_like(theta, bool), div)
    assert out[5, 0] == 9.0 and not smoothed.any()  # each side is constant on its own
    out1, _ = smooth_held(theta, np.ones_like(theta, bool), div, width=1)
    assert np.array_equal(out1, theta)
