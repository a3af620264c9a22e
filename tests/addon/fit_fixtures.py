"""Helpers of the add-on's fit-option tests (``test_fit_cues.py``,
``test_fit_default_on_options.py``): the opt-in options, the default-on ones, a stand-in
scene folder and the CLI; their fixtures are in ``conftest.py``."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from core.calibration_io import write_calibration
from core.camera import Camera, rodrigues_to_matrix
from core.state import write_state

from .state_fixtures import synthetic_state


class Option(NamedTuple):
    """One of the fit's opt-in options, by its keyword of ``pipeline.run_fit`` (and
    property of the panel)."""

    field: str  # core's SequenceSettings field it turns on
    flag: str  # the CLI flag of `fit` and `batch`
    label: str  # the panel's check box
    help: tuple  # words the flag's help holds
    description: tuple  # words the property's tooltip holds


OPTIONS = {
    "feet_from_points": Option(
        "foot_heading",
        "--feet-from-points",
        "Feet from points",
        (
            "--feet-from-points turn each foot about its shin at the clicked frame",
            "contours give no points",
        ),
        ("heading of the surface points", "Texture or Both"),
    ),
    "smooth_motion": Option(
        "smooth_motion",
        "--smooth",
        "Smooth motion",
        (
            "--smooth smooth the fitted motion over the take",
            "less jitter on walks and jumps",
            "a sudden kick of one limb",
        ),
        ("over the take", "less jitter on walks and jumps", "sudden kick of one limb", "fit anew"),
    ),
}


class DefaultOn(NamedTuple):
    """One of the fit's default-on options, by its keyword of ``pipeline.run_fit`` (and
    property of the panel): on is core's default too, so it is the switch off that
    reaches core."""

    field: str  # core's SequenceSettings field it sets
    on: object  # that field's value on: core's default
    off: object  # that field's value off
    flag: str  # the CLI flag of `fit` and `batch` that turns it off
    record: str  # its name in fake_run_fit's record when off (the flag's argparse dest)
    label: str  # the panel's check box
    help: tuple  # words the flag's help holds
    description: tuple  # words the property's tooltip holds
    cues: str  # the cues its tests fit with
    after: str  # the option drawn (and named in the CLI's errors) right before it


# in the panel's order, after the opt-in options
DEFAULT_ON = {
    "contour_starts": DefaultOn(
        "contour_starts",
        True,
        False,
        "--prediction-start-only",
        "prediction_start_only",
        "Extra starts (contours alone)",
        ("--prediction-start-only", "contours alone", "from the prediction only"),
        ("without texture points", "three starts", "about 2x", "fast limbs"),
        "contours",
        "smooth_motion",
    ),
    "late_shape": DefaultOn(
        "late_shape_points",
        100,
        None,
        "--one-pass",
        "one_pass",
        "Second pass (late shape)",
        ("--one-pass", "fit the motion once", "late shape", "half the fit time"),
        ("hardly saw", "second time", "About 2x", "one pass"),
        "both",
        "contour_starts",
    ),
    "flow_choice": DefaultOn(
        "flow_choice",
        True,
        False,
        "--one-flow",
        "one_flow",
        "Refined-flow second fit",
        (
            "--one-flow",
            "the silhouettes shape",
            "least squares matching",
            "foregrounds explain better",
            "twice the fit time",
        ),
        ("silhouettes alone", "second time", "LSM-refined", "About twice", "one fit"),
        "contours",
        "late_shape",
    ),
}


def make_scene(root, with_fit=False):
    """A scene folder with a 2-camera calibration (and a fit.json of 3 frames)."""
    root.mkdir(parents=True)
    cams = [
        Camera(
            f"cam{i}",
            (64, 48),
            [[80, 0, 32], [0, 80, 24], [0, 0, 1]],
            np.zeros(5),
            rodrigues_to_matrix([1.6, 0, 0.5 * i]),
            [0, -1, 5],
        )
        for i in range(2)
    ]
    write_calibration(root / "calibration.toml", cams)
    (root / "scene.toml").write_text("# stand-in: core's fit is replaced in these tests\n")
    if with_fit:
        write_state(root / "fit.json", synthetic_state(3, seed=3))
    return root


def cli(argv):
    from addon.cli_command import main

    return main([str(a) for a in argv])
