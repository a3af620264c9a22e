"""Weights and solver settings of the whole-body shape fit (:class:`ShapeSettings`).

The options of :func:`core.shape_fit.fit_shape` (which re-exports this class) and of its
least-squares problem (:class:`core.shape_problem.ShapeProblem`): the σ of every
observation type and prior, the model-point penalty, the re-weighting rounds and the
bounds of the radii.  Lengths in metres, image distances in pixels.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class ShapeSettings:
    """Weights and solver settings of :func:`core.shape_fit.fit_shape` (lengths in metres)."""

    sigma_point: float = 0.003  # σ of a data point's distance (when none is given)
    sigma_model: float = 0.004  # σ of a seen model point's distance to the data
    sigma_radius: float = 0.03  # prior towards the start radii
    sigma_center: float = 0.02  # prior towards the start centres
    sigma_symmetry: float = 0.003  # left/right symmetry of radii and centres (0: off)
    #: σ of the symmetry of a pair, or of a mid-plane metaball's centre on the plane,
    #: whose data points lie on one side (:func:`core.shape_priors.one_sided`; 0: off,
    #: as ``sigma_symmetry``).  At ``sigma_symmetry`` a trunk metaball drifts towards the
    #: seen side and thins the unseen one (jumps_line3 at the exact clicks: the trunk's
    #: right side 17-20 mm inside the true mesh).  0.5 mm helps there (surface 10.9 ->
    #: 10.0 mm, visibility 0.052 -> 0.048) but not with the clicks moved by 0.5 px,
    #: where the skeleton itself sits 5-10 mm off in depth and a centre held on its
    #: plane cannot follow: visibility 0.052 / 0.044 / 0.050 -> 0.059 / 0.056 / 0.059.
    #: Off by default (docs/design.md, "The side no point sees")
    sigma_one_sided: float = 0.0
    one_sided_ratio: float = 0.25  # one-sided: the emptier side below this share
    sigma_smooth: float = 0.01  # neighbours along a bone: radii and displacements (0: off)
    free_centers: bool = True
    model_points: bool = True  # the penalty against bulging (needs cameras)
    k_members: int = 8  # metaballs in a point's field
    samples_per_ball: int = 40  # model points drawn per metaball and frame
    min_views: int = 2  # cameras that must see a model point
    depth_tol: float = 0.02  # z-buffer tolerance of the model points
    neighbours: int = 5  # data points whose median normal offset a model point uses
    max_offset: float = 0.05  # cap of a model point's offset
    model_gate: float = 0.01  # offsets below this are no bulge (curvature, point spacing)
    #: Cauchy knee of a seen model point's offset beyond the gate, in ``sigma_model``, in
    #: a frame whose silhouettes are fitted too (0: every bulge weighs fully).  No
    #: tracked point where the model's surface is seen is as often a gap in the points
    #: (tracks lost, weak texture, a limb in front in other frames) as a bulge; weighed
    #: fully, a gap pulls the surface in across it (make demo's walk: the trunk's
    #: metaballs 16–29 mm off the true mesh, 11–21 with it).  With points alone the model
    #: points are all that holds a bulge and keep their full weight
    model_robust_scale: float = 3.0
    robust_scale: float = 3.0  # Cauchy knee of the data points, in σ
    rounds: int = 10
    max_nfev: int = 15
    tol: float = 1e-4
    round_tol: float = 2e-4  # converged when no radius or centre moved more than this
    cost_tol: float = 0.01  # ... or the cost changed by less than this share in a round
    min_radius: float = 0.005
    #: every radius stays within [start / ratio, start · ratio] (0: only ``min_radius``):
    #: overlapping metaballs can trade widths along nearly flat directions of the cost,
    #: and left free some collapse into needles while a neighbour swells
    radius_ratio: float = 2.0
    min_points: int = 20  # a frame with fewer data points is left out (flagged)
    #: σ of a silhouette contour pair of the blended surface [px] (0: off; needs the
    #: frames' contours, :func:`core.shape_fit.fit_shape` ``contours``)
    sigma_silhouette_px: float = 1.0
    huber_silhouette_px: float = 3.0  # Huber knee of those pairs [px]
    max_dist_silhouette_px: float = 12.0  # largest rim ↔ contour pairing distance [px]
