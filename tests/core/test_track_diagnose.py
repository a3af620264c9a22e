"""The step that lost a tracked point (core.track_diagnose)."""

import numpy as np

from core.track_diagnose import REASONS, loss_reasons, tally


def test_each_point_is_blamed_on_the_first_step_that_left_it_short():
    # one point per reason, in the order of REASONS, plus a measured one (not lost)
    rows = {  # searchable, searched, temporal, unconfirmed, rms_ok, two, depth_out
        "depth_dev": (3, 3, 3, 0, True, True, True),
        "gate": (3, 3, 3, 0, True, True, False),
        "intersection_rms": (3, 3, 2, 0, False, True, False),
        "too_few_cameras": (1, 1, 1, 0, False, False, False),
        "occlusion": (3, 1, 1, 0, False, False, False),
        "temporal": (3, 3, 1, 0, False, False, False),
        "confirm_rekey": (3, 3, 2, 1, False, False, False),
        "spatial": (3, 3, 3, 0, False, False, False),
    }
    cols = list(zip(*rows.values(), strict=True))
    arr = [np.array(c + (c[0],)) for c in cols]
    lost = np.r_[np.ones(len(rows), bool), False]
    code = loss_reasons(lost, *arr)
    assert [REASONS[k] for k in code[:-1]] == list(rows)
    assert code[-1] == -1
    t = tally(np.stack([code, code]))
    assert all(t[name] == 2 for name in rows)
