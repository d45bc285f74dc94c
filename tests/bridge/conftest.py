"""Bridge tier: real Blender through the ``bpy`` module, factory reset per test."""
import os
import sys

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


#: bpy 4.2 crashes (SIGSEGV) and 4.5 hangs at interpreter exit after any glTF export once SciPy's optimize module
#: is loaded (`import bpy, scipy.optimize; bpy.ops.export_scene.gltf(filepath="x.glb")` is enough; no ShapeSpace
#: code involved). Tests marked ``gltf_export`` set a flag; on those versions the test process then ends with
#: ``os._exit(exit status)`` after pytest has printed its summary, so the glTF tests run on every Blender we claim.
_GLTF_EXPORTED = pytest.StashKey[bool]()
_EXIT_STATUS = pytest.StashKey[int]()


@pytest.fixture(autouse=True)
def gltf_export_guard(request):
    """Note that the session exported glTF (tests marked ``gltf_export``; see the note above) or generated a Rigify
    rig (Rigify loaded: the same exit crash and hang follow, so every test that builds one is guarded, marked or
    not)."""
    if request.node.get_closest_marker("gltf_export") is not None:
        request.config.stash[_GLTF_EXPORTED] = True
    yield
    if "rigify" in sys.modules:
        request.config.stash[_GLTF_EXPORTED] = True


def pytest_sessionfinish(session, exitstatus):
    session.config.stash[_EXIT_STATUS] = int(exitstatus)


@pytest.hookimpl(trylast=True)
def pytest_unconfigure(config):
    if bpy.app.version < (5, 0, 0) and config.stash.get(_GLTF_EXPORTED, False):
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(config.stash.get(_EXIT_STATUS, 1))
