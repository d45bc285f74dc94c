"""Core-tier test setup: make the repository root importable as the ``core`` package's parent."""
import os
import sys

REPO_ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), os.pardir, os.pardir))
if sys.path[0] != REPO_ROOT:
    sys.path.insert(0, REPO_ROOT)
