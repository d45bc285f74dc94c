"""Shared test setup.

Blender must never touch the user's real configuration: before ``bpy`` is
imported anywhere, point every Blender user folder at a temporary directory.
"""
import os
import sys
import tempfile

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
