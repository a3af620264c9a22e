"""Settings of silhouette contours as an observation of the fit (:class:`ContourSettings`).

One dataclass of options (re-exported by :mod:`core.fit_contours`), read by the contour
observation type of the per-frame fit (:class:`core.fit_contours.ContourFrame`), its
pairing with the model's rim (:func:`core.contour_pairs.match_frame`), the sequence fit
(:mod:`core.fit`, :mod:`core.fit_depth`) and the scene's foreground contours
(:func:`core.fit_contours.scene_contours`).  Units are given per field: image
distances in pixels, lengths in metres, angles in degrees.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class ContourSettings:
    """Contour observations in the fit (units in brackets)."""

    sigma_px: float = 3.0  # a-priori σ of one contour observation [px]
    huber_px: float = 4.0  # knee of the Huber weights [px]
    max_dist_px: float = 12.0  # largest contour ↔ rim pairing distance [px]
    min_visibility: float = 0.2  # a part uses a camera with a visibility index ≥ this
    select: bool = True  # per-part camera selection (False: all cameras fused)
    #: with selection: also rank a part's visible cameras by its predicted contour motion
    #: (the paper's observability); False: every camera with visibility >= min_visibility
    rank_motion: bool = True
    #: body parts that use no contours (names of core.skeleton bones), e.g. the head,
    #: whose template metaballs do not follow a real head's outline (hair, face)
    skip_parts: tuple = ()
    min_matches: int = 40  # a contours-only frame with fewer pairs is diverged
    max_rms_px: float = 6.0  # ... or with a larger RMS of its inlier pairs [px]
    min_part_matches: int = 30  # a part with fewer pairs is hidden to the contours
    #: with points: contours may un-hide a part the points miss.  Off since the tracker
    #: seeds surface across depth jumps (``core track``, :mod:`core.surface_seed`): a
    #: part that two cameras see then has points, and one the points miss is one whose
    #: depth the contours of the line rig cannot fix — un-hidden, it swung away in
    #: depth.  make demo's walk (line3, cues both) with those tracks: un-hiding 27.0 mm
    #: (1 frame diverged, right wrist 148 mm) -> 13.0 mm (none, right wrist 57 mm).
    #: Without the seeding un-hiding was the better choice (the old tracks: 18.1 vs
    #: 25.7 mm; bench.looks' old tracks: 25.7 vs 44.5 mm).
    unhide: bool = False
    #: ... only when its pairs come from at least this many cameras (10 pairs each): one
    #: view's occluding contours leave the part's depth free.  Truth-derived points +
    #: contours on walk_ortho3 (the walker's right limbs seen by no two cameras): 1 ->
    #: MPJPE 75.0 mm, 8 frames diverged; 2 -> 38.3 mm, none (texture alone 27.1 mm).
    #: walk_line3, real tracks: 25.8 -> 25.1 mm, limb segments 43.8 -> 28.2 deg.
    #: Frames with contours alone (no points) un-hide from one view as before.
    unhide_views: int = 2
    #: with contours alone: a part whose pairs come from one camera only keeps its
    #: joints' depth along that camera's rays at the previous frame's, with this σ [m]
    #: (:mod:`core.fit_depth`; None: off).  bench.looks' call, contours alone: skin
    #: look 34.1 -> 27.9 mm, walk_ortho3 26.9 -> 18.9 mm (σ 1.5 cm: 29.6 / 32.5, 6 cm:
    #: 26.6 / 22.6 mm).  Hiding such parts instead
    #: (all their angles held): skin 27.8 mm, walk_ortho3 58.1 mm (both legs lost).
    depth_sigma_m: float | None = 0.03
    #: ... and so does a part whose views' rays to it are at most this many degrees
    #: apart (held along their mean direction): views a few tens of degrees apart see
    #: nearly the same outline (:func:`core.fit_depth.narrow_depth_holds`; 0: one view
    #: only).  line3's outer cameras are 38° apart.  Contours alone, 0 -> 40: sweater
    #: 33.2 -> 26.3 mm, skin 27.9 -> 25.6, jumps_line3 30.0 -> 25.0; pirouette_line3
    #: with selection 176.1 -> 40.3 (fused 39.8 -> 61.2), dance_line3 fused 162.6 ->
    #: 68.2 (selection 205.2 -> 207.7).  The orthogonal rig's views are 90° apart.
    depth_spread_deg: float = 40.0
    #: with selection: a part whose selected views lie within ``depth_spread_deg`` of
    #: each other (as lines of sight) also uses one visible camera at least this many
    #: degrees across them, the best ranked by the part's predicted motion (None: the
    #: paper's selection alone).  The ranking keeps the views that see a limb swing and
    #: can drop the one that sees where it lies across them.  walk_ortho3 (cues both,
    #: bench.fit_spread, 6 runs): MPJPE median 14.8 -> 14.2 mm, range 13.2-17.0 ->
    #: 13.3-15.5, run 0 15.7 -> 14.2 (limb segments median 24.4 -> 23.7 deg);
    #: dance_ortho3, one run: 60.4 mm over 41 frames (9 diverged) -> 64.6 over all 50.
    #: line3's views lie within 38 deg of each other: nothing is added there (make
    #: demo's fit byte-identical).
    wide_view_deg: float | None = 60.0
    #: ... where a view counts, and a camera is added, only if it shows at least this
    #: many of the part's rim points on the body's outline (an arm in front of the trunk
    #: has none there; 0: every view counts).  4, against 0: walk_ortho3, 6 runs, 12.8 /
    #: 13.8 / 15.4 / 14.8 / 14.7 / 13.2 mm, median 14.3 (14.2 / 14.0 / 14.2 / 15.5 / 15.1
    #: / 13.3, median 14.2; run 0's left wrist in frames 27-33 114 -> 10 mm), limb
    #: segments median 24.6 deg (23.7); dance_ortho3 46.8 mm over 41 frames, 9 diverged
    #: (64.6 over 50, none) -- no clearer than the spread: off
    wide_view_outline: int = 0
    #: with selection: the views the selection leaves out are paired too, their pairs'
    #: σ times this (None: left out, the paper's selection; 1: every view alike, as
    #: fused).  A part the model misplaces is the one whose visibility it misjudges;
    #: left out of the views that would pull it back, it stays lost.  None -> 2 (cues
    #: both, in-process, MPJPE mm): dance_ortho3 27.7 -> 23.5 and 35.5 -> 28.3 (exact
    #: clicks, click draw 1; fused 25.1, 29.7), pirouette_ortho3 25.2 -> 28.6 and 40.1
    #: -> 27.1 (fused 36.7, 27.5), pirouette_line3 50.6 -> 46.5 (fused 59.1); make
    #: demo's walk, runs 0-3 of bench.fit_spread, 9.87 / 13.59 / 17.13 / 13.22 -> 9.60
    #: / 13.62 / 15.05 / 13.08; walk_ortho3 13.25 / 12.57 / 12.62 / 13.06 -> 11.77 /
    #: 13.32 / 13.10 / 13.06; jumps_line3 13.78 -> 13.38 (docs/design.md)
    unselected_sigma_scale: float | None = 2.0
    textured_scale: float = 1.0  # σ of the pairs of parts that texture points observe, × this
    spacing_px: float = 2.0  # sampling of the image contours [px]
    rim_samples: int = 32  # model rim samples per metaball
    outer_px: float = 3.0  # only rim points with no model pixel this far out (0: all)
    background_frames: int = 20  # frames (evenly spaced) in the background medians
    rounds: int = 3  # re-pairing (re-weighting) rounds per pose solve, at least
    #: σ of the silhouette-containment term [px] (0: off): points inside the metaballs of
    #: the parts the texture points miss must project into every camera's foreground
    #: (:meth:`core.fit_contours.ContourFrame.containment_block`,
    #: :func:`core.fit_contours.containment_parts`; frames with points only).  Walk,
    #: line3, real tracks, cues both: make demo's tracks MPJPE 29.2
    #: -> 18.1 mm (right wrist 173 -> 63 mm), bench.looks' tracks 25.1 -> 25.7 mm;
    #: walk_ortho3, truth-derived points: 38.3 -> 33.0 mm.  σ 2 px: 24.6 / 24.4 mm; every
    #: part (containment_textured) σ 3 px: 21.0 / 22.3 / 32.8 mm, σ 2 px: 34.5 / 23.7 mm.
    containment_px: float = 3.0
    containment_tol_px: float = 2.0  # ... tolerated distance outside the foreground [px]
    containment_textured: bool = False  # ... also for the parts the texture points observe
    min_fg_frac: float = 0.002  # a foreground mask covering less of the image, ...
    max_fg_frac: float = 0.5  # ... or more, gives no contours for that view
    #: shaping the body from the clicked frame's silhouettes (contours alone, or too few
    #: points there): the metaball centres of these parts leave their template places,
    #: about them with σ ``shape_center_sigma_m`` [m] (None: centres held).  The template
    #: sets trunk, head and feet metaballs on their bones' axes, where a real body's
    #: flesh is not; held there, the silhouettes push the skeleton off in every frame.
    #: The arms keep theirs: too thin for their silhouettes to place them apart from
    #: the pose.
    shape_center_sigma_m: float | None = 0.02
    shape_center_parts: tuple = (
        "pelvis",
        "lowerback",
        "spine",
        "chest",
        "neck",
        "head",
        "l_hip",
        "l_knee",
        "l_ankle",
        "r_hip",
        "r_knee",
        "r_ankle",
    )
    #: ... and these parts keep their template shape there (opt-in): radii about the
    #: template's with σ ``shape_held_sigma_m`` [m] (the rest: 2 cm), centres held
    #: (whatever ``shape_center_parts`` says).  One frame's three outlines leave the
    #: head's three overlapping metaballs free to trade their sizes: on pirouette_ortho3
    #: two became discs (visible semi-axes 63 × 48 × 13 and 120 × 93 × 36 mm) whose rim
    #: stands out of the silhouettes in every frame.  Held (``("head",)``),
    #: pirouette_ortho3's four click draws gain 2–8 mm, but walk_ortho3's lose
    #: 2.5–3.5 mm, whose head the silhouettes shape well (docs/design.md, "A head shaped
    #: from one frame's silhouettes")
    shape_held_parts: tuple = ()
    shape_held_sigma_m: float = 0.002
    #: σ [px] of the silhouette shape fit's containment (opt-in; 0: off): every
    #: metaball's rendered surface inside every camera's foreground
    #: (:mod:`core.shape_containment`).  At 2 px it turns pirouette_ortho3's head discs
    #: back into a head (surface 12.10 -> 10.57 mm, visibility index 0.058 -> 0.055 on
    #: the exact clicks; MPJPE 29.2 / 31.5 / 27.4 / 22.6 mm over the four click draws,
    #: 27.9 / 33.8 / 28.7 / 28.4 without), but dance_ortho3 is worse in two draws
    #: (27.6 / 39.1 / 42.9 / 29.4 mm, 24.2 / 27.8 / 25.1 / 38.8 without) and walk_ortho3
    #: run 0 goes 11.0 -> 11.6 mm (docs/design.md, "A head shaped from one frame's
    #: silhouettes")
    shape_containment_px: float = 0.0
    #: a take shaped from its clicked frame's silhouettes: after the fit, the radii
    #: re-solved over this many of its fitted frames (evenly spaced among those not
    #: diverged; their poses about the fitted ones with σ ``shape_frames_pose_sigma_rad``
    #: / ``shape_frames_root_sigma_m``, the centres held), and the motion fitted again
    #: with that shape (:mod:`core.contour_shape_frames`; 0 or 1: off, and off in a
    #: one-pass fit, ``SequenceSettings.late_shape_points`` None).  One frame's
    #: three outlines leave radii free that its posture hides; the fitted take shows
    #: them.  bench.fit_spread, four click draws, 0 -> 5 (MPJPE mm): pirouette_ortho3
    #: 27.9 / 33.8 / 28.7 / 28.4 -> 22.4 / 24.7 / 24.3 / 20.9, dance_ortho3 24.2 / 27.8 /
    #: 25.1 / 38.8 -> 24.5 / 25.6 / 26.9 / 27.5, walk_ortho3 11.0 / 10.9 / 12.9 / 11.8 ->
    #: 11.2 / 11.1 / 10.1 / 12.2, jumps_ortho3 10.0 / 10.3 / 11.0 / 10.9 -> 10.3 / 10.8 /
    #: 10.6 / 11.2 (docs/design.md, stop 66).  On by default since stop 67: the written
    #: body (from the clicked frame's shape, ``fit_sequence(shape_start=)``) keeps its
    #: visibility index, draws 0-3 default -> 5: walk_ortho3 0.048 / 0.045 / 0.048 /
    #: 0.045 -> 0.047 / 0.049 / 0.049 / 0.053, jumps_ortho3 0.038 / 0.047 / 0.045 / 0.042
    #: -> 0.040 / 0.044 / 0.040 / 0.037, dance_ortho3 0.049 / 0.046 / 0.047 / 0.052 ->
    #: 0.049 / 0.046 / 0.049 / 0.054, pirouette_ortho3 0.058 / 0.067 / 0.062 / 0.054 ->
    #: 0.052 / 0.056 / 0.063 / 0.049 (the mean of the sixteen 0.0495 -> 0.0485).  It
    #: doubles such a take's fit time (0 or ``core fit --one-pass``: one pass).  That
    #: shape written with the first fit's
    #: motion instead puts jumps_ortho3's metaball surface 45-51 mm from the true mesh
    #: (11.8 mm by default): the outlines fit a union of ellipsoids, and radii hidden
    #: inside it swell the blended field; the second pass writes its shape from the
    #: points again
    shape_fit_frames: int = 5
    shape_frames_pose_sigma_rad: float = 0.1
    shape_frames_root_sigma_m: float = 0.02
    #: ... the radii along each metaball's bone (its z) about the clicked frame's with this
    #: σ [m] (None: as the others): a chain's outline hardly shows them.  Free, they grew
    #: by up to 26 cm (jumps_ortho3's spine), and run 0 went: jumps 10.3 -> 9.2, dance
    #: 24.5 -> 27.9, walk 11.2 -> 10.0, pirouette 22.4 -> 21.3 mm; its limb segments
    #: 17.4 -> 23.6 deg, the walk's 17.1 -> 18.8; the jumps' draws 1-3 10.8 / 10.6 / 11.2
    #: -> 13.0 / 12.0 / 12.2, the dance's 25.6 / 26.9 / 27.5 -> 29.7 / 50.1 / 26.6
    shape_frames_along_sigma_m: float | None = 0.002
    #: ... only where two cameras see the body from directions at least this many
    #: degrees apart: views close together leave every radius along them to the prior,
    #: which five frames' outlines outweigh.  The skin look (bench.looks, walk_line3's
    #: rig, 39 deg) with it: 15.4 -> 17.2 mm, limb segments 20.2 -> 32.7 deg
    shape_frames_min_spread_deg: float = 60.0
