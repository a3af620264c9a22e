"""Fixtures for the add-on suite (marker ``blender``): the bpy module, a clean file."""

from __future__ import annotations

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
