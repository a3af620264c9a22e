"""core.nan_median: np.nanmedian's values to the bit, along any axis."""

import warnings

import numpy as np
import pytest

from core.nan_median import nanmedian


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("axis", [0, 1, 2])
def test_nanmedian_equals_numpy_bit_for_bit(dtype, axis):
    rng = np.random.default_rng(8)
    for n in (1, 2, 3, 7, 8, 27, 30):
        shape = [40, 40, 3]
        shape[axis] = n
        a = rng.normal(0, 0.3, shape).astype(dtype)
        a[rng.random(a.shape) < 0.35] = np.nan
        np.moveaxis(a, axis, 0)[:, :3] = np.nan  # slices with no value
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            want = np.nanmedian(a, axis=axis)
        got = nanmedian(a, axis=axis)
        assert got.dtype == want.dtype and got.shape == want.shape
        np.testing.assert_array_equal(got, want)
