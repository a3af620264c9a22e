"""core.vec3: the same bits as numpy's reductions over a last axis of length 3."""

import numpy as np

from core.vec3 import norm3, sum3


def test_sum3_and_norm3_equal_numpys_reductions_to_the_bit():
    rng = np.random.default_rng(5)
    a = rng.normal(size=(300, 84, 3)) * np.exp(rng.normal(0, 3, (300, 84, 1)))
    for x in (a, a[:, ::3], np.swapaxes(a, 0, 1), a.astype(np.float32)):
        np.testing.assert_array_equal(sum3(x), np.sum(x, axis=-1))
        np.testing.assert_array_equal(norm3(x), np.linalg.norm(x, axis=-1))
    strided = np.moveaxis(rng.normal(size=(3, 50, 7)), 0, -1)  # last axis not contiguous
    np.testing.assert_array_equal(sum3(strided), np.sum(strided, axis=-1))
    np.testing.assert_array_equal(norm3(strided), np.linalg.norm(strided, axis=-1))
