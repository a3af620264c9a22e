"""Sums and Euclidean norms over a last axis of length 3, without numpy's reductions.

``np.sum(a, axis=-1)`` and ``np.linalg.norm(a, axis=-1)`` over three components go
through numpy's general reduction machinery, which costs several times the arithmetic
for arrays such as the (N points, M metaballs, 3) local coordinates of the field.
:func:`sum3` adds the components left to right, ``(a₀ + a₁) + a₂`` — the order numpy's
reduction uses for a length-3 axis, so the results are the same to the bit (checked
by ``tests/core/test_vec3.py``) — and :func:`norm3` is ``sqrt(sum3(a * a))`` as
``np.linalg.norm`` computes it.  About 3× faster on (2300, 84, 3).
"""

from __future__ import annotations

import numpy as np


def sum3(a: np.ndarray) -> np.ndarray:
    """``np.sum(a, axis=-1)`` for ``a`` of shape (..., 3): shape (...)."""
    return (a[..., 0] + a[..., 1]) + a[..., 2]


def norm3(a: np.ndarray) -> np.ndarray:
    """``np.linalg.norm(a, axis=-1)`` for real ``a`` of shape (..., 3): shape (...)."""
    return np.sqrt(sum3(a * a))
