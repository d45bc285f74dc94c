"""Bridge tier: real Blender through the ``bpy`` module, factory reset per test."""
import pytest

bpy = pytest.importorskip("bpy")

import package  # tools/package.py  # noqa: E402

SS = package.load()


@pytest.fixture(scope="session")
def registered():
    """The extension's classes and CLI command, registered once for the session."""
    SS.register()
    yield SS
    SS.unregister()


@pytest.fixture(autouse=True)
def factory_reset():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield
