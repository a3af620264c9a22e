"""Outcome of batched least squares matching: per-patch status codes and the result arrays.

:class:`Status` enumerates why a patch was accepted or rejected, :class:`LSMResult`
holds the N matches of one :func:`core.lsm.match` call: matched points and their
covariance in search-image pixels, the affine part of the warp (search-image offsets
per template pixel offset), the radiometric gain and offset (grey levels) and the
texture measure of each template.  Both are re-exported by :mod:`core.lsm`.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np


class Status(IntEnum):
    """Per-match outcome of :func:`core.lsm.match` (``LSMResult.status``)."""

    OK = 0
    NOT_CONVERGED = 1  #: no convergence within ``max_iter`` iterations
    LARGE_SIGMA = 2  #: σ of the shifts above ``max_sigma_px``
    WEAK_TEXTURE = 3  #: template without texture (small gradient energy)
    OUT_OF_SEARCH = 4  #: the shift drifted more than ``max_shift_px`` from its start
    OUT_OF_IMAGE = 5  #: template or warped patch leaves its image
    DEGENERATE = 6  #: singular normal matrix, affine scale / gain out of range, or a
    #: flat search patch (grey-level spread below :data:`core.lsm_design.FLAT_SD`)
    INVALID = 7  #: NaN start position


@dataclass
class LSMResult:
    """Result of :func:`core.lsm.match` for N patches.

    Attributes
    ----------
    uv : ndarray, shape (N, 2)
        Matched point in the search image, pixels (the last estimate, also for failures).
    affine : ndarray, shape (N, 2, 2)
        ``[[a1, a2], [b1, b2]]``: search-image offsets per template pixel offset.
    gain, offset : ndarray, shape (N,)
        Radiometric parameters ``r1`` and ``r0`` (grey levels).
    sigma0 : ndarray, shape (N,)
        Standard deviation of unit weight: RMS grey-level residual, grey levels.
    cov_uv : ndarray, shape (N, 2, 2)
        Covariance of ``uv``, px² (``κ σ0² N⁻¹`` mapped by the affine part, see :mod:`core.lsm`).
    iterations : ndarray, shape (N,), int
    status : ndarray, shape (N,), int
        :class:`Status` codes; 0 = accepted.
    texture : ndarray, shape (N,)
        sqrt of the smaller eigenvalue of the template's structure tensor per pixel,
        grey levels per pixel (the "weak texture" measure).
    """

    uv: np.ndarray
    affine: np.ndarray
    gain: np.ndarray
    offset: np.ndarray
    sigma0: np.ndarray
    cov_uv: np.ndarray
    iterations: np.ndarray
    status: np.ndarray
    texture: np.ndarray

    @property
    def ok(self) -> np.ndarray:
        """Accepted matches, shape (N,) bool."""
        return self.status == Status.OK

    @property
    def sigma_uv(self) -> np.ndarray:
        """Standard deviations of u and v, shape (N, 2), pixels."""
        return np.sqrt(np.abs(np.diagonal(self.cov_uv, axis1=1, axis2=2)))
