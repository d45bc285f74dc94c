"""Shared test setup.

Blender must never touch the user's real configuration: before ``bpy`` is
imported anywhere, point every Blender user folder at a temporary directory.
"""
import os
import sys
import tempfile

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
USER_DIR = tempfile.mkdtemp(prefix="shapespace-blender-user-")
os.environ["BLENDER_USER_RESOURCES"] = USER_DIR
for var in ("BLENDER_USER_CONFIG", "BLENDER_USER_SCRIPTS", "BLENDER_USER_DATAFILES", "BLENDER_USER_EXTENSIONS"):
    os.environ.pop(var, None)

if ROOT not in sys.path:
    sys.path.insert(0, ROOT)
TOOLS = os.path.join(ROOT, "tools")
if TOOLS not in sys.path:
    sys.path.insert(0, TOOLS)


def pytest_addoption(parser):
    parser.addoption("--run-slow", action="store_true", default=False,
                     help="also run the tests marked slow (perf and scale; tools/run_tests.py passes it)")


def pytest_collection_modifyitems(config, items):
    """Tests marked ``slow`` are skipped unless ``--run-slow`` is given: a plain ``pytest tests/core`` is the fast
    inner loop, ``python tools/run_tests.py`` runs everything."""
    if config.getoption("--run-slow"):
        return
    skip = pytest.mark.skip(reason="slow (perf/scale): run with --run-slow, as tools/run_tests.py does")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)
