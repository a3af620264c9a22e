"""Fixtures for the add-on suite (marker ``blender``): the bpy module, a clean file."""

from __future__ import annotations

import os
import sys

import pytest


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
