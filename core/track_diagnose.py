"""Why a tracked point stopped being measured: the first step of the tracker that lost it.

:func:`core.tracking.track` measures a point at frame i+1 through a chain of steps
(cameras to search, the occlusion test, NCC + temporal LSM, the key-template check,
the spatial LSM, the forward intersection with its reprojection and Mahalanobis gate,
the depth test against the neighbours).  For every point that was measured at frame i
and is not at i+1, :func:`loss_reasons` names the step that left it with fewer than
two usable cameras (or rejected its intersection), walking the chain from its end:

======================  ==================================================================
``depth_dev``           measured, then dropped as a depth outlier (:mod:`core.track_smooth`)
``gate``                a candidate intersection passed the reprojection test but lay
                        beyond the Mahalanobis gate of the prediction
``intersection_rms``    two or more cameras accepted, every intersection reprojected
                        worse than ``max_rms_px``
``too_few_cameras``     fewer than two cameras had a last measurement and an image (or
                        the prediction left the image)
``occlusion``           the occlusion test (:mod:`core.track_occlusion`) left fewer than two
``temporal``            NCC / temporal LSM / key matches in fewer than two cameras (and no
                        spatial re-acquisition made up for it)
``confirm_rekey``       two or more temporal matches, but the ones whose key match failed
                        were not confirmed by a spatial match
``spatial``             two or more temporal matches, vetoed by the spatial matches
======================  ==================================================================

Shapes: P points, C cameras.
"""

from __future__ import annotations

import numpy as np

#: Loss reasons, in the order of their codes (0 .. 7); -1 means "not lost here".
REASONS = (
    "depth_dev",
    "gate",
    "intersection_rms",
    "too_few_cameras",
    "occlusion",
    "temporal",
    "confirm_rekey",
    "spatial",
)


def loss_reasons(
    lost: np.ndarray,
    n_searchable: np.ndarray,
    n_searched: np.ndarray,
    n_temporal: np.ndarray,
    n_rekey_unconfirmed: np.ndarray,
    any_rms_ok: np.ndarray,
    any_two: np.ndarray,
    depth_out: np.ndarray,
) -> np.ndarray:
    """Code (index into :data:`REASONS`) of the step that lost each point.

    Parameters
    ----------
    lost : ndarray, shape (P,), bool
        Measured in the previous frame, not in this one.
    n_searchable : ndarray, shape (P,), int
        Cameras with a last measurement, an image and a prediction inside it.
    n_searched : ndarray, shape (P,), int
        Of those, the cameras left by the occlusion test.
    n_temporal : ndarray, shape (P,), int
        Cameras with a temporal match (after the key-template check).
    n_rekey_unconfirmed : ndarray, shape (P,), int
        Temporal matches whose key match failed and that no spatial match confirmed.
    any_rms_ok : ndarray, shape (P,), bool
        Some candidate set of two or more cameras intersected within the reprojection
        limit (the gate rejected it, or the depth test after it).
    any_two : ndarray, shape (P,), bool
        Some candidate set had two or more cameras.
    depth_out : ndarray, shape (P,), bool
        Dropped by the depth test after being measured.

    Returns
    -------
    ndarray, shape (P,), int8
        -1 where not ``lost``.
    """
    code = np.select(
        [
            depth_out,
            any_rms_ok,
            any_two,
            n_searchable < 2,
            n_searched < 2,
            n_temporal < 2,
            n_temporal - n_rekey_unconfirmed < 2,
        ],
        [0, 1, 2, 3, 4, 5, 6],
        default=7,
    )
    return np.where(lost, code, -1).astype(np.int8)


def tally(codes: np.ndarray) -> dict[str, int]:
    """Count of each reason among codes (any shape, -1 ignored)."""
    c = np.asarray(codes).ravel()
    n = np.bincount(c[c >= 0].astype(int), minlength=len(REASONS))
    return {name: int(k) for name, k in zip(REASONS, n, strict=True)}
