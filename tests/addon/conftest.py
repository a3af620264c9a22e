"""Fixtures for the add-on suite (marker ``blender``): the bpy module, a clean file."""

from __future__ import annotations

import inspect
import os
import sys

import pytest

from core.state import write_state

from .fit_fixtures import OPTIONS
from .state_fixtures import synthetic_state


@pytest.fixture(scope="session")
def bpy_module():
    """The ``bpy`` module (Blender as a Python module); skips when it is not installed."""
    return pytest.importorskip("bpy")


@pytest.fixture
def empty_blend(bpy_module):
    """A factory-default, empty Blender file for one test."""
    bpy_module.ops.wm.read_factory_settings(use_empty=True)
    yield bpy_module
    bpy_module.ops.wm.read_factory_settings(use_empty=True)


@pytest.fixture
def makehuman(shared_data, bpy_module):
    """The shared MakeHuman character (.blend saved by Blender 5.0, whose file format
    Blender 4.x cannot read: skipped there)."""
    if bpy_module.app.version < (5, 0, 0):
        pytest.skip(
            "the shared MakeHuman .blend is in Blender 5.0's file format, "
            f"unreadable by Blender {bpy_module.app.version_string}"
        )
    return shared_data / "characters" / "makehuman_cmu_mb.blend"


# -- the fit options' tests (test_fit_cues.py, test_fit_default_on_options.py) --------


@pytest.fixture
def fake_run_fit(bpy_module, monkeypatch):
    """Replace ``addon.pipeline.run_fit``: record ``(scene, cues, *options that are on)``
    (e.g. ``("walk", "both", "smooth_motion")``, then ``"prediction_start_only"`` when
    ``contour_starts`` is off, ``"one_pass"`` when ``late_shape`` is and ``"one_flow"``
    when ``flow_choice`` is), write a 4-frame state."""
    from addon import pipeline

    calls = []

    def run_fit(
        scene_dir,
        out_json,
        progress=None,
        cues="texture",
        clicks_xyz=None,
        feet_from_points=False,
        smooth_motion=False,
        contour_starts=True,
        late_shape=True,
        flow_choice=True,
    ):
        on = {"feet_from_points": feet_from_points, "smooth_motion": smooth_motion}
        off = () if contour_starts else ("prediction_start_only",)
        off += () if late_shape else ("one_pass",)
        off += () if flow_choice else ("one_flow",)
        calls.append((scene_dir.name, cues, *(name for name in OPTIONS if on[name]), *off))
        write_state(out_json, synthetic_state(4, seed=len(calls)))
        return out_json

    # the stand-in takes what the real one takes
    assert inspect.signature(run_fit).parameters.keys() == (
        inspect.signature(pipeline.run_fit).parameters.keys()
    )
    monkeypatch.setattr(pipeline, "run_fit", run_fit)
    return calls


@pytest.fixture
def fake_fit_scene(bpy_module, monkeypatch):
    """Replace core's scene loading and ``fit_scene``: record each call's keywords."""
    from core import fit_scene, scene

    calls = []

    def fit(sc, progress=None, **kwargs):
        calls.append(kwargs)
        return synthetic_state(5, seed=11)

    monkeypatch.setattr(scene, "load_scene", lambda path, **kw: ("scene", path))
    monkeypatch.setattr(fit_scene, "fit_scene", fit)
    return calls


@pytest.fixture
def registered(empty_blend):
    import addon

    addon.register()
    yield empty_blend
    addon.unregister()


def pytest_sessionfinish(session, exitstatus):
    session.config.stash[_EXIT] = int(exitstatus)


_EXIT = pytest.StashKey[int]()


@pytest.hookimpl(trylast=True)
def pytest_unconfigure(config):
    """The bpy 4.2 module crashes (SIGSEGV) at interpreter exit once Rigify has been
    enabled; after pytest has reported everything, leave with pytest's own status."""
    bpy = sys.modules.get("bpy")
    if bpy is not None and bpy.app.version < (4, 3, 0) and _EXIT in config.stash:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(config.stash[_EXIT])
