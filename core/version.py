"""ShapeSpace's version: read from ``blender_manifest.toml``, the one place it is written.

The manifest sits at the extension's root (in the repository and in every built zip), so the version
Blender shows in its Extensions list, the one the command line prints and the one ``info`` reports are the
same string.
"""
from __future__ import annotations

import os
import tomllib

__all__ = ["MANIFEST", "version"]

#: The extension's manifest, two levels up from this module (``<root>/core/version.py``).
MANIFEST = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "blender_manifest.toml")


def version() -> str:
    """The ``version`` field of the extension's manifest, e.g. ``"0.2.0"``."""
    with open(MANIFEST, "rb") as fh:
        return tomllib.load(fh)["version"]
