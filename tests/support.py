"""Paths of test assets."""
import os

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHARED = os.environ.get("SHAPESPACE_DATA", os.path.join(os.path.dirname(ROOT), "shared", "data"))
ASSETS = os.path.join(ROOT, "assets")


def shared(*parts) -> str:
    """Path of a shared real asset; the test is skipped only when shared/ is absent altogether."""
    if not os.path.isdir(SHARED):
        pytest.skip(f"shared assets not found at {SHARED} (set SHAPESPACE_DATA)")
    path = os.path.join(SHARED, *parts)
    assert os.path.exists(path), f"missing shared asset {path}"
    return path
