"""A source rig from another .blend (the command line's ``--source-rig FILE.blend:OBJECT``): appended for the
transfer and removed again, so the saved file keeps none of it."""
from __future__ import annotations

import os

import bpy

from ...core.errors import ErrorCode
from ...core.result import ShapeSpaceError

__all__ = ["append_object", "remove_appended"]

_ID_COLLECTIONS = ("actions", "armatures", "brushes", "cache_files", "cameras", "collections", "curves", "fonts",
                   "grease_pencils", "grease_pencils_v3", "hair_curves", "images", "lattices", "libraries",
                   "lightprobes", "lights", "linestyles", "masks", "materials", "meshes", "metaballs", "movieclips",
                   "node_groups", "objects", "paint_curves", "palettes", "particles", "pointclouds", "scenes",
                   "screens", "shape_keys", "sounds", "speakers", "texts", "textures", "volumes", "workspaces",
                   "worlds")


def _all_ids() -> dict:
    out = {}
    for attr in _ID_COLLECTIONS:
        coll = getattr(bpy.data, attr, None)
        if coll is None:
            continue
        for idb in coll:
            out[idb.as_pointer()] = idb
    return out


def append_object(path: str, name: str) -> tuple:
    """Append object ``name`` (with what it uses) from the .blend ``path``, local to this file.

    Returns ``(object, appended)``: ``appended`` lists every datablock the append created, for
    :func:`remove_appended` (the output file keeps none of them).
    """
    if not os.path.isfile(path):
        raise ShapeSpaceError(f"file not found: {path}", ErrorCode.MISSING_FILE)
    before = set(_all_ids())
    try:
        with bpy.data.libraries.load(path, link=False) as (data_from, data_to):
            if name not in data_from.objects:
                shown = ", ".join(sorted(data_from.objects)[:8])
                raise ShapeSpaceError(f"{path} has no object named {name!r} (objects: {shown or 'none'})",
                                      ErrorCode.MISSING_OBJECT)
            data_to.objects = [name]
    except OSError as exc:
        raise ShapeSpaceError(f"cannot read {path}: {exc}", ErrorCode.CORRUPT_FILE) from None
    appended = [idb for ptr, idb in _all_ids().items() if ptr not in before]
    obj = next((o for o in data_to.objects if o is not None), None)
    if obj is None:
        remove_appended(appended)
        raise ShapeSpaceError(f"cannot append {name!r} from {path}", ErrorCode.CORRUPT_FILE)
    return obj, appended


def remove_appended(appended: list) -> None:
    """Remove the datablocks :func:`append_object` created (nothing else of the file is touched)."""
    alive = set(_all_ids())
    ids = []
    for idb in appended:
        try:
            if idb.as_pointer() in alive:
                ids.append(idb)
        except ReferenceError:        # already gone
            continue
    if ids:
        bpy.data.batch_remove(ids)
