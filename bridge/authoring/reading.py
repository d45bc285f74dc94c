"""Reading the source rig and the target mesh of a transfer into arrays (main thread).

:func:`read_source_rig` and :func:`read_target` refuse what would corrupt the transfer (not a mesh, Edit Mode, no
vertices or faces, NaN, damaged keys, a non-finite slider range), naming the culprit; :func:`target_signature` is
what a later write checks to be unchanged.  The arrays are :class:`core.authoring.job.SourceRig` and
:class:`~core.authoring.job.TargetMesh`.
"""
from __future__ import annotations

import numpy as np

from ...core.authoring.job import SourceRig, TargetMesh
from ...core.authoring.mesh import triangle_parts
from ...core.errors import ErrorCode
from ...core.result import ShapeSpaceError
from ...core.validate import ABSURD_COORDINATE, coordinates
from .. import driven, part_objects, shapekeys
from ..arrays import read_float
from ..meshes import triangles, vertex_groups

__all__ = ["SourceRig", "TargetMesh", "read_source_rig", "read_target", "mesh_object", "read_neutral", "finite",
           "target_signature", "with_part_objects"]


def mesh_object(obj, role: str):
    """``obj`` when it is a mesh with vertices, not in Edit Mode; else refused naming its ``role``."""
    if obj is None:
        raise ShapeSpaceError(f"choose the {role} mesh", ErrorCode.NO_OBJECT)
    if obj.type != "MESH":
        raise ShapeSpaceError(f"the {role} {obj.name!r} is a {obj.type.lower()}, not a mesh", ErrorCode.NOT_MESH)
    if obj.mode == "EDIT":
        raise ShapeSpaceError(f"the {role} {obj.name!r} is in Edit Mode: leave Edit Mode first", ErrorCode.MODE)
    if len(obj.data.vertices) == 0:
        raise ShapeSpaceError(f"the {role} {obj.name!r} has no vertices", ErrorCode.EMPTY)
    return obj


def read_neutral(obj) -> np.ndarray:
    """The object's neutral: its reference key's positions, else the mesh's, (n, 3) float64."""
    key = obj.data.shape_keys
    if key is not None and len(key.key_blocks):
        return read_float(key.reference_key.points, "co", 3).astype(np.float64)
    return read_float(obj.data.vertices, "co", 3).astype(np.float64)


def finite(obj, role: str, name: str, co: np.ndarray) -> None:
    """Refuse non-finite or absurd coordinates ``co`` of ``obj``, naming the object, its role and ``name``."""
    coordinates(co, f"{role} {obj.name!r}: {name}", ABSURD_COORDINATE, fix="fix the mesh")


def read_source_rig(obj) -> SourceRig:
    """Read a rig to transfer from (refuses one without targets, NaN, or damaged keys, naming the culprit)."""
    mesh_object(obj, "source rig")
    errors = [i for i in shapekeys.check_shape_keys(obj) if i.severity == "error"]
    if errors:
        raise ShapeSpaceError(f"source rig: {errors[0].message}", errors[0].code)
    key = obj.data.shape_keys
    ref = key.reference_key
    blocks = [kb for kb in key.key_blocks if kb != ref]
    coords = {kb.name: read_float(kb.points, "co", 3).astype(np.float64) for kb in key.key_blocks}
    shapekeys.check_coordinates(obj, coords, ref.name, "source rig")
    meta = driven.prune(key)
    names = [kb.name for kb in blocks]
    deltas = np.stack([coords[kb.name] - coords[(kb.relative_key or ref).name] if kb.relative_key != kb
                       else np.zeros_like(coords[ref.name]) for kb in blocks])
    used_groups = {kb.name: kb.vertex_group for kb in blocks if kb.vertex_group}
    groups, weights = {}, {}
    if used_groups:
        cache = vertex_groups(obj)
        for key_name, group in used_groups.items():
            if group in cache[2]:            # Blender ignores a mask naming a missing group: so do we
                groups[key_name] = group
                idx = cache[2].index(group)
                weights[group] = np.where(cache[0] == idx, cache[1], 0.0).sum(axis=1).astype(np.float64)
    lo = np.array([kb.slider_min for kb in blocks], dtype=np.float64)
    hi = np.array([kb.slider_max for kb in blocks], dtype=np.float64)
    if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
        bad = next(kb.name for kb in blocks if not (np.isfinite(kb.slider_min) and np.isfinite(kb.slider_max)))
        raise ShapeSpaceError(f"source rig {obj.name!r}: shape key {bad!r} has a non-finite slider range",
                              ErrorCode.NON_FINITE)
    return SourceRig(name=obj.name, neutral=coords[ref.name], triangles=triangles(obj.data), names=names,
                     deltas=deltas, slider_min=lo, slider_max=hi,
                     mute=np.array([kb.mute for kb in blocks], dtype=bool), groups=groups, group_weights=weights,
                     inbetweens=meta["inbetweens"], combinations=meta["combinations"])


def read_target(obj) -> TargetMesh:
    """Read the mesh to transfer onto: its neutral (reference key, else the mesh), triangles, keys, parts."""
    mesh_object(obj, "target")
    key = obj.data.shape_keys
    if key is not None:
        errors = [i for i in shapekeys.check_shape_keys(obj) if i.severity == "error" and i.code != "no_targets"]
        if errors and errors[0].code != "no_shape_keys":
            raise ShapeSpaceError(f"target: {errors[0].message}", errors[0].code)
    rest = read_neutral(obj)
    finite(obj, "target", "the neutral", rest)
    tris = triangles(obj.data)
    if not len(tris):
        raise ShapeSpaceError(f"the target {obj.name!r} has no faces: transfer needs a surface", ErrorCode.EMPTY)
    keys = [kb.name for kb in key.key_blocks] if key is not None else []
    parts = len(triangle_parts(len(rest), tris)[1])
    return TargetMesh(name=obj.name, neutral=rest, triangles=tris, keys=keys, parts=parts)


def target_signature(target, parts=()) -> tuple:
    """What a transfer's or Find Parts' write depends on: mode, link state, vertices (the neutral), faces, shape
    keys and groups, and the part objects' (:func:`bridge.part_objects.signature`)."""
    key = target.data.shape_keys
    keys = tuple(kb.name for kb in key.key_blocks) if key is not None else ()
    return (target.mode, target.library is not None or target.data.library is not None, len(target.data.vertices),
            read_neutral(target).tobytes(), triangles(target.data).tobytes(), keys,
            tuple(g.name for g in target.vertex_groups), part_objects.signature(target, list(parts)))


def with_part_objects(target, source, tgt: TargetMesh, parts) -> TargetMesh:
    """``tgt`` with the part objects ``parts`` appended (their rows after the target's own; ``source`` is
    refused among them, None for none)."""
    verts, tris, objects = part_objects.read_part_objects(target, source, parts, len(tgt.neutral), triangles,
                                                          finite)
    if not objects:
        return tgt
    neutral, tri = np.vstack([tgt.neutral, verts]), np.vstack([tgt.triangles, tris])
    return TargetMesh(name=tgt.name, neutral=neutral, triangles=tri, keys=tgt.keys,
                      parts=len(triangle_parts(len(neutral), tri)[1]), own=len(tgt.neutral), objects=objects)
