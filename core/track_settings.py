"""Options of :func:`core.tracking.track`, with their measured effects.

:class:`TrackSettings` holds every keyword option of the tracker with its default; the
figures quoted come from ``bench.tracking`` on ``sample_scenes/walk_line3``.  Options
that were measured and left off are listed in docs/design.md ("Tried and left off").
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace


@dataclass(frozen=True)
class TrackSettings:
    """Keyword options of :func:`core.tracking.track` (all have defaults).

    Attributes
    ----------
    half : int
        Half width of the matched patches (NCC and LSM templates: ``2 half + 1``
        pixels square).
    predict : {"ekf", "linear"}
        Start of the temporal search: the per-point 3-D Kalman prediction projected
        into each camera, or the paper's 2-D linear prediction (same image motion as
        in the last step, no motion where unknown).
    ncc_radius, first_radius : int
        NCC search box half widths with a velocity estimate and without one, pixels
        (``predict="linear"`` or ``adaptive=False``).
    adaptive : bool
        With ``predict="ekf"``: box half width ``3 σ + 1`` of the projected prediction
        covariance, within ``[3, max_radius]`` px, instead of the fixed radii.
    max_radius : int
        Largest half width of the ``adaptive`` box, pixels.
    agree_px : float
        Largest distance between a camera's temporal match and a converged spatial
        match into it, pixels; farther, the spatial match vetoes the temporal one.
    max_rms_px : float
        Largest reprojection RMS of an accepted forward intersection, pixels.
    accel_sigma : float
        Process noise of the point filters, m / frame².
    gate : float
        Largest Mahalanobis distance between a measured point and its prediction.
    max_coast : int
        Frames a point may go unmeasured (occluded, no match, a failed check) before
        it is dropped (or goes dormant); meanwhile it is carried by its neighbours'
        motion (``coast_neighbours``) and searched from its last templates at that
        prediction, and the gaps so bridged are filled afterwards
        (:attr:`Tracks.measured` is False there).  Before the neighbour prediction
        and the ``coast_m`` gate (and the key templates, ``confirm_rekey``, the
        occlusion and depth tests), 3 frames raised the 95th percentile of the 3-D
        error over 50 frames to ~90 mm.  With them, on walk_line3 (50 frames,
        ``bench.tracking --no-compare --track-kw '{"max_coast": N}'``, 2,048 frame-0
        points): N = 0 / 2 / 3 -> measured in every frame 25.1 / 25.0 / 23.1 %, kept
        to the last frame with flagged gaps of <= 5 frames 25.1 / 29.4 / 29.0 %, 95th
        percentile of the measured positions 9.56 / 10.30 / 10.05 mm (bridged
        point-frames: 95th 17.9 / 16.9 mm) with ``coast_m=0.01`` and no
        ``coast_confirm``.  With both as now (default 1): N = 1 / 2 -> 25.8 / 23.8 %,
        27.0 / 26.7 %, 9.69 / 9.79 mm (bridged 13.7 / 15.4 mm); live at the last frame
        96.3 % (100.3 % with N = 0: coasting points hold their grid cells against
        regeneration).
    temporal_sigma : float or None
        Gaussian weighting σ of the temporal LSM patches, pixels (None: uniform).
    max_sigma_px : float
        Largest σ of an accepted temporal match, pixels.  With the other defaults on
        walk_line3 (50 frames), 0.15: measured in every frame 25.6 -> 26.6 %, 95th
        percentile 9.67 -> 9.79 mm.
    spatial_sigma_px : float
        Largest σ of an accepted spatial match (and of the regenerated surface points),
        pixels.
    fallback : bool
        Where the accepted cameras fail the intersection or the gate, try the
        temporal matches alone (also those a spatial match vetoed).
    regen_every : int
        Regenerate / seed new points every this many frames (0: never).  3 (with
        ``depth_dev_m``, which drops points every frame): the live count at the last
        of 50 frames on walk_line3 stays at 101 % of the first (82 % with 5).
    anchor : bool
        Match every temporal match again from the point's key template
        (:mod:`core.track_anchor`): removes the drift of frame-to-frame matching.
        On walk_line3 (50 frames) frame-0 points measured in every frame 32.3 ->
        35.8 %, error median 3.82 -> 3.59 mm, 95th percentile 35.9 -> 36.9 mm; about
        20 % more CPU time.
    anchor_px : float
        Largest distance between the key match and the temporal match, pixels; beyond
        it (or where the key match fails) the key is reset to the new measurement.
    confirm_rekey : bool
        A temporal match whose key match failed (its key would be reset to it) is
        accepted only where a spatial match from another camera converged within
        ``agree_px`` of it (the appearance changed: occlusion, or a slip onto other
        texture), and it is not used by the fallback.  Without it, a point that a
        leg or arm passed in front of took the occluder's texture as its new key and
        followed it.  walk_line3, 50 frames (``bench.tracking``, all else as before):
        95th percentile of the 3-D error 18.3 -> 13.1 mm, median 2.95 -> 2.74 mm,
        frame-0 points measured in every frame 33.5 -> 29.0 %.
    occlusion_m : float, optional
        Cameras in which a point's prediction lies more than this behind the surface
        of the other live points' predictions (:func:`core.track_occlusion.occluded`)
        are not matched for it in that frame (None: no test).  walk_line3 as above,
        0.05 alone: 95th 18.3 -> 13.0 mm, measured in every frame 33.5 -> 28.3 %; with
        ``confirm_rekey``: 11.4 mm, 26.6 %.
    occlusion_dilate : bool
        Passed to :func:`core.track_occlusion.occluded` as ``dilate_all``.
    reacquire_radius : int
        Where fewer than two cameras have a temporal match, the spatial matches into
        the others start at the predicted point: search them first by NCC (template:
        the spatial template camera's match) in a box of ``3 σ + 1`` of the prediction,
        at most this half width, pixels.  0 (default): LSM from the prediction.  On
        walk_line3 (50 frames, other defaults) 8: frame-0 points measured in every
        frame 25.6 -> 26.4 %, 95th percentile 9.67 -> 9.71 mm, median 2.34 -> 2.43 mm.
    depth_dev_m : float, optional
        A point whose intersection lies farther than this in depth from the median of
        its 8 nearest measured neighbours in the same frame
        (:func:`core.track_smooth.depth_outliers`) is not measured there; regenerated
        surfaces are filtered the same way (None: no test).  walk_line3 with the two
        options above and the frame-0 surface filtered alike (2,006 of 2,124
        points): 0.01 -> 95th 9.0 mm, median 2.26 mm, measured in every frame
        25.4 %, live at the last frame 82 % (101 % with ``regen_every=3``: 95th
        9.7 mm, 25.6 %); 0.015 -> 10.3 mm, 28.0 %, 94 %.  Measured against the
        neighbours' local plane (their depth fitted on their offsets across the ray)
        instead of their median depth (``bench.tracking --no-compare``, at e73476e):
        0.01 -> measured in every frame 26.5 %, 95th 10.72 mm; 0.006 -> 22.6 %, 9.55 mm;
        0.004 -> 17.8 %, 8.42 mm; the median at 0.01: 26.2 %, 9.69 mm -- kept.
    coast_neighbours : bool
        A coasting point (``max_coast``) is carried by the rigid motion of its measured
        neighbours (:func:`core.track_reacquire.predict_unmeasured`) instead of its own
        constant-velocity prediction: that starts the next frame's search, and bridges
        the gap when it is measured again (:func:`bridge_gaps`; else :func:`fill_gaps`).
    coast_confirm : bool
        The temporal matches of a coasting point are accepted only where a spatial
        match confirms them (as ``confirm_rekey``).
    coast_m : float, optional
        A coasting point is measured again only within this distance of its
        prediction, metres (None: the Mahalanobis ``gate`` alone).
    neighbour_radius_m : float
        Radius of the neighbours whose rigid motion carries coasting and dormant
        points, metres.
    max_dormant : int
        Frames a lost point is kept dormant (after ``max_coast``) and searched again
        (:mod:`core.track_reacquire`): predicted from the rigid motion of its
        neighbours that moved with it, re-acquired from its key templates in
        ``reacquire_views`` or more cameras within ``reacquire_m`` of that prediction;
        the trajectory resumes with the same index and the gap is bridged from the
        predictions (:func:`bridge_gaps`, :attr:`Tracks.measured` False there).
        0 (default): never.  On walk_line3 (50 frames, with ``anchor``) 10 frames
        raised the frame-0 points through every frame from 35.8 to 37.3 % but the 95th
        percentile of the error from 36.9 to 39.4 mm (bridged point-frames: median
        13 mm); with ``reacquire_views=3, reacquire_m=0.006``: 36.4 %, 38.5 mm,
        bridged median 5.6 mm.  Without the rate test on the neighbours, wrong
        re-acquisitions on the crossing legs raised the 95th percentile to 100 mm.
        With the current defaults (``bench.tracking --no-compare --max-dormant 10``):
        measured in every frame 25.6 -> 26.9 %, through every frame with bridged gaps
        29.3 %, 95th percentile of the measured positions 9.67 -> 10.98 mm (bridged
        point-frames: median 5.5 mm, 95th 17.5 mm).
    reacquire_m : float
        Largest distance between a re-acquired point and its prediction, metres.
    reacquire_views : int
        Cameras in which a dormant point must be found again.
    reacquire_checks : bool
        Dormant points are not searched in cameras where their prediction is occluded
        by the measured cloud (``occlusion_m``) and are not re-acquired as depth
        outliers (``depth_dev_m``; :func:`core.track_reacquire.dormant_step`).
    jump_seeds : bool
        When regenerating, also seed surface that no growth reaches — a limb beside or
        behind the trunk, across a depth jump — by a depth search along the epipolar
        lines (:func:`core.surface_seed.grow_from_jumps`).  walk_line3 (``core track``,
        which seeds the frame-0 surface the same way): the right arm, which no frame
        had a point on, gets 150–270 points in frames 0–7 and 25–34 (points > 2 cm from
        the true mesh: as many as without); with the contours no longer un-hiding the
        parts the points miss (:attr:`core.fit_contours.ContourSettings.unhide`) the
        fit of make demo's walk went from 18.1 to 13.0 mm.
    pair_seeds : bool
        When regenerating (and, in ``core track --pair-seeds``, at frame 0), also
        measure the surface that the reference camera does not see from every pair of
        the other cameras (:mod:`core.surface_pairs`): through line3 the far leg behind
        the near one, hidden in the middle camera, seen by the outer two.  Off: on make
        demo's walk it adds 219 points at frame 0 (2,510 → 2,729, most on the right
        shin and foot) and 2.7 % more point-frames, their distance to the true mesh the
        same (median 1.75 mm, 95th 7.68 → 7.56 mm), yet the fit of those tracks is worse
        (``bench.fit_spread`` draws 0 / 1: 11.09 / 13.51 → 11.83 / 14.70 mm; the neck
        and the right shoulder moved, not the leg).  On jumps_line3, where the far leg
        shows only slivers at its outline, it adds a few points on the right forearm
        (frames 9 and 36–45) and none on the leg: draws 0–3 14.43 / 15.70 / 15.82 /
        15.31 → 14.41 / 15.00 / 16.07 / 15.87 mm.  The outer cameras are 38° apart:
        the epipolar search's 13 × 13 correlation across them finds few seeds.  On
        the real video (``bench.realvideo --frames 20``) 3 more trajectories of 499,
        tracking 59.9 → 83.2 s.
    step : int
        Grid step of the regenerated surface (:func:`core.surface.measure_surface`),
        pixels.
    """

    half: int = 6
    predict: str = "ekf"
    ncc_radius: int = 5
    first_radius: int = 14
    adaptive: bool = True
    max_radius: int = 16
    agree_px: float = 0.5
    max_rms_px: float = 1.0
    accel_sigma: float = 0.025
    gate: float = 5.0
    max_coast: int = 1
    temporal_sigma: float | None = 4.0
    max_sigma_px: float = 0.12
    spatial_sigma_px: float = 0.15
    fallback: bool = True
    regen_every: int = 3
    anchor: bool = True
    anchor_px: float = 1.0
    confirm_rekey: bool = True
    occlusion_m: float | None = 0.05
    occlusion_dilate: bool = True
    reacquire_radius: int = 0
    depth_dev_m: float | None = 0.01
    coast_neighbours: bool = True
    coast_confirm: bool = True
    coast_m: float | None = 0.006
    neighbour_radius_m: float = 0.06
    max_dormant: int = 0
    reacquire_m: float = 0.01
    reacquire_views: int = 2
    reacquire_checks: bool = True
    jump_seeds: bool = True
    pair_seeds: bool = False
    step: int = 2

    def __post_init__(self):
        if self.predict not in ("ekf", "linear"):
            raise ValueError(f"predict must be 'ekf' or 'linear', got {self.predict!r}")

    @classmethod
    def of(cls, settings: TrackSettings | None = None, **options) -> TrackSettings:
        """``settings`` (default: the defaults) with ``options`` replaced.

        Raises
        ------
        TypeError
            An option that :class:`TrackSettings` does not have (as an unknown keyword
            argument would).
        """
        unknown = sorted(set(options) - {f.name for f in fields(cls)})
        if unknown:
            raise TypeError(f"track() got unexpected keyword arguments: {', '.join(unknown)}")
        return replace(settings if settings is not None else cls(), **options)
