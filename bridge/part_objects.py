"""Separate part objects of a Transfer Shapes target (issue #22 §1): eyes, teeth and tongue as meshes of their
own, as Ready Player Me ships them (``EyeLeft``, ``EyeRight``, ``Wolf3D_Teeth`` beside ``Wolf3D_Head``).

The target's *Part Objects* collection names them (``transfer --parts-collection`` on the command line).
They are read into the target's object space and appended to its mesh, so registration, deformation transfer
and the facial parts (``core.authoring.parts``) see one head; each part object then gets shape keys of the
same names, its slice of the result turned back into its own object space.  Read and checked with the target
(nothing is written until every object's plan holds); written after the head, each object in one step as the
head is (:func:`bridge.authoring._write`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import bpy
import numpy as np

from ..core.errors import ErrorCode
from ..core.result import ShapeSpaceError
from .arrays import read_float
from .meshes import triangles

__all__ = ["PartObject", "meshes_of", "own_neutral", "read_part_objects", "to_part_space", "signature"]


@dataclass
class PartObject:
    """One part object as read: where its vertices sit in the joined target and how to get back."""

    name: str
    start: int                                  # first row in the joined target
    count: int                                  # its vertices
    linear: np.ndarray                          # (3, 3) part-local vectors → target-local vectors
    keys: list = field(default_factory=list)    # its existing shape keys (reference first)


def meshes_of(collection, target) -> list:
    """The mesh objects of ``collection`` (and its children) but ``target``, in name order; [] for None."""
    if collection is None:
        return []
    return sorted((ob for ob in collection.all_objects if ob.type == "MESH" and ob != target), key=lambda ob: ob.name)


def own_neutral(ob) -> np.ndarray:
    """A part object's neutral in its own object space (its reference key, else its mesh)."""
    key = ob.data.shape_keys
    if key is not None and len(key.key_blocks):
        return read_float(key.reference_key.points, "co", 3).astype(np.float64)
    return read_float(ob.data.vertices, "co", 3).astype(np.float64)


def _check(ob, source) -> None:
    if ob == source:
        raise ShapeSpaceError(f"part object {ob.name!r} is the source rig: take it out of the Parts collection",
                              ErrorCode.SAME_KEY)
    if ob.mode == "EDIT":
        raise ShapeSpaceError(f"part object {ob.name!r} is in Edit Mode: its data there is not saved yet; go back "
                              f"to Object Mode", ErrorCode.MODE)
    if ob.library is not None or ob.data.library is not None:
        raise ShapeSpaceError(f"part object {ob.name!r} is linked from a library: make it local first",
                              ErrorCode.LINKED)


def read_part_objects(target, source, objects, start: int, triangles_of, check_finite) -> tuple:
    """Read the part objects into the target's object space.

    Parameters
    ----------
    target, source : bpy.types.Object
    objects : sequence of bpy.types.Object
        The part objects (:func:`meshes_of`).
    start : int
        The target's own vertex count (the parts' rows follow it).
    triangles_of : callable(mesh) -> ndarray (f, 3)
    check_finite : callable(obj, role, what, coords)
        The target reader's own finiteness check (names the object, vertex and axis).

    Returns
    -------
    neutral : ndarray (p, 3), triangles : ndarray (g, 3) (joined indices), parts : list of PartObject
    """
    inv_target = np.linalg.inv(np.array(target.matrix_world))
    verts, tris, parts = [], [], []
    for ob in objects:
        _check(ob, source)
        co = own_neutral(ob)
        check_finite(ob, "part object", "the neutral", co)
        M = inv_target @ np.array(ob.matrix_world)
        t = triangles_of(ob.data)
        if not len(t):
            raise ShapeSpaceError(f"part object {ob.name!r} has no faces", ErrorCode.EMPTY)
        key = ob.data.shape_keys
        parts.append(PartObject(ob.name, start, len(co), M[:3, :3].copy(),
                                [kb.name for kb in key.key_blocks] if key is not None else []))
        verts.append(co @ M[:3, :3].T + M[:3, 3])
        tris.append(t + start)
        start += len(co)
    if not parts:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), []
    return np.concatenate(verts), np.concatenate(tris), parts


def to_part_space(part: PartObject, rows: np.ndarray) -> np.ndarray:
    """Target-space vectors (..., count, 3) of ``part``'s rows turned into its own object space."""
    return rows @ np.linalg.inv(part.linear).T


def signature(target, objects) -> tuple:
    """What a write depends on for the part objects: names, modes, vertex counts, keys, neutral, faces,
    placement (theirs and the target's, evaluated now: a move since the last evaluation counts); a part object
    gone reads as None."""
    if not objects:
        return ()
    bpy.context.view_layer.update()
    out = [tuple(np.round(np.array(target.matrix_world), 9).ravel())]
    for ob in objects:
        if ob is None or ob.type != "MESH":
            out.append(None)
            continue
        key = ob.data.shape_keys
        out.append((ob.name, ob.mode, len(ob.data.vertices), tuple(kb.name for kb in key.key_blocks) if key else (),
                    tuple(np.round(np.array(ob.matrix_world), 9).ravel()), own_neutral(ob).tobytes(),
                    triangles(ob.data).tobytes()))
    return tuple(out)
