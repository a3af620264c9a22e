"""NCC search on seeded synthetic images with known shifts."""

from __future__ import annotations

import numpy as np

from bench.patches import make_pairs
from core.ncc import NCCStatus, search


def test_finds_integer_and_subpixel_shifts():
    P = make_pairs(200, seed=1, size=41, max_shift=4.0, noise=2.0, fmax=0.15)
    n = len(P.template)
    c = np.full((n, 2), P.centre)
    r = search(
        P.template, P.search, c, c, radius=6, template_index=np.arange(n), search_index=np.arange(n)
    )
    assert r.ok.mean() > 0.95
    err = np.abs(r.uv - P.uv_true)[r.ok]
    assert np.max(err) < 0.5
    assert np.median(err) < 0.2
    assert np.all(r.score[r.ok] > 0.8)


def test_subpixel_template_position_carries_over():
    P = make_pairs(50, seed=2, max_shift=2.0, noise=0.0, fmax=0.15)
    n = len(P.template)
    c = np.full((n, 2), P.centre)
    r = search(
        P.template, P.search, c + 0.3, c, template_index=np.arange(n), search_index=np.arange(n)
    )
    assert np.median(np.abs(r.uv - (P.uv_true + 0.3))) < 0.2


def test_bad_points_flagged():
    P = make_pairs(4, seed=3, max_shift=0.0, noise=2.0)
    T = P.template.copy()
    T[1] = 50
    c = np.full((4, 2), P.centre)
    c_s = c.copy()
    c_s[2] = [3.0, 3.0]
    c_s[3] = np.nan
    r = search(
        T, P.search, c, c_s, radius=4, template_index=np.arange(4), search_index=np.arange(4)
    )
    assert r.status[0] == NCCStatus.OK
    assert r.status[1] == NCCStatus.FLAT
    assert r.status[2] == NCCStatus.OUT_OF_IMAGE
    assert r.status[3] == NCCStatus.INVALID


def test_shift_beyond_the_box_is_at_border_or_low():
    P = make_pairs(30, seed=4, max_shift=0.0, noise=2.0, fmax=0.2)
    n = len(P.template)
    c = np.full((n, 2), P.centre)
    r = search(
        P.template,
        P.search,
        c,
        c + 6.0,
        radius=3,
        template_index=np.arange(n),
        search_index=np.arange(n),
        min_score=0.8,
    )
    assert not np.any(r.ok & (np.linalg.norm(r.uv - P.uv_true, axis=1) > 1.0))
