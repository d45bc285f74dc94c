"""Load the repository as the ``shapespace`` package (as Blender would load the extension).

The repo root *is* the extension, so its modules use relative imports
(``from ..core import …``).  Tools and tests import it under the name
``shapespace`` through this helper instead of installing it.
"""
from __future__ import annotations

import importlib.util
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
NAME = "shapespace"


def load(register: bool = False):
    """Import the repo as ``shapespace`` (needs ``bpy``) and optionally register it."""
    if NAME in sys.modules:
        pkg = sys.modules[NAME]
    else:
        spec = importlib.util.spec_from_file_location(
            NAME, os.path.join(ROOT, "__init__.py"), submodule_search_locations=[ROOT])
        pkg = importlib.util.module_from_spec(spec)
        sys.modules[NAME] = pkg
        spec.loader.exec_module(pkg)
    if register:
        pkg.register()
    return pkg
