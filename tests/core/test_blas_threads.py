"""The OpenBLAS thread limit around batched matching is scoped and restored."""

from __future__ import annotations

import numpy as np

from core.blas_threads import blas_threads, single_blas_thread


def test_single_blas_thread_is_scoped_and_nests():
    before = blas_threads()
    with single_blas_thread():
        assert blas_threads() in (None, 1)
        with single_blas_thread():
            assert blas_threads() in (None, 1)
        assert blas_threads() in (None, 1)
        a = np.ones((64, 64))
        assert np.allclose(a @ a, 64.0)
    assert blas_threads() == before


def test_decorated_function_restores_on_error():
    before = blas_threads()

    @single_blas_thread()
    def boom():
        raise RuntimeError("x")

    try:
        boom()
    except RuntimeError:
        pass
    assert blas_threads() == before
