"""Loading files through Blender's own readers (.blend, glTF, FBX, BVH)."""
from __future__ import annotations

import os

import bpy

from ..core.result import ShapeSpaceError

IMPORTERS = {
    ".glb": ("import_scene", "gltf"),
    ".gltf": ("import_scene", "gltf"),
    ".fbx": ("import_scene", "fbx"),
    ".bvh": ("import_anim", "bvh"),
}


def load(path: str, replace: bool = True) -> list:
    """Open a .blend or import a glTF/FBX/BVH file; return the names of the new objects.

    Parameters
    ----------
    path : str
    replace : bool
        For imports: start from an empty scene first (``read_factory_settings``).

    Raises
    ------
    core.ShapeSpaceError
        Missing file, unsupported extension, or a file Blender cannot read.
    """
    if not os.path.isfile(path):
        raise ShapeSpaceError(f"file not found: {path}", "missing_file")
    ext = os.path.splitext(path)[1].lower()
    if ext == ".blend":
        try:
            bpy.ops.wm.open_mainfile(filepath=path, load_ui=False)
        except RuntimeError as exc:
            raise ShapeSpaceError(f"cannot read {path}: {_first_line(exc)}", "corrupt_file") from None
        return [ob.name for ob in bpy.data.objects]
    if ext not in IMPORTERS:
        raise ShapeSpaceError(
            f"unsupported file type {ext or '(none)'} for {path}; use .blend, .glb, .gltf, .fbx or .bvh",
            "unsupported_file")
    if replace:
        bpy.ops.wm.read_factory_settings(use_empty=True)
    before = set(bpy.data.objects.keys())
    group, name = IMPORTERS[ext]
    op = getattr(getattr(bpy.ops, group), name)
    try:
        result = op(filepath=path)
    except (RuntimeError, ValueError, KeyError, IndexError, OSError) as exc:
        raise ShapeSpaceError(f"cannot read {path}: {_first_line(exc)}", "corrupt_file") from None
    if "FINISHED" not in result:
        raise ShapeSpaceError(f"cannot read {path}: the importer gave up", "corrupt_file")
    return [n for n in bpy.data.objects.keys() if n not in before]


def _first_line(exc) -> str:
    text = str(exc).strip().splitlines()
    text = [t for t in text if t.strip()]
    return (text[-1] if text else type(exc).__name__).replace("Error: ", "").strip()
