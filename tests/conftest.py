"""Shared pytest fixtures.

Only bpy fixtures live here, and bpy is imported inside them: the core tests
never import bpy.
"""
import pytest


@pytest.fixture
def factory_scene():
    """An empty factory-settings file; returns its (only) scene."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    return bpy.context.scene
