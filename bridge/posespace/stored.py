"""What the pose-space capability stores on a mesh, and the names of what it creates.

Each example (``SHAPESPACE_PG_example``) keeps four JSON strings, read and
written through :mod:`bridge.storage` with a versioned schema:

- ``pose`` — where in pose space it was sculpted (the feature vector);
- ``pseudo_pose`` — where it is interpolated when moved (Shape-by-Example
  pseudo-example), empty otherwise;
- ``target_values`` — the driven targets' values recorded at it;
- ``final_shape`` — its sculpted posed shape, rig pose and input fingerprint
  (:data:`FINAL_SHAPE_SCHEMA`; see :mod:`.finalshape`).

The schemas are declared in :mod:`core.blobs`.  This module also holds the names ShapeSpace gives what it
creates (the sculpt copy's suffix, weighted PSD's key, the post-deformation modifier) and pins settings whose
default changed (:func:`pin_settings`, after each load and before each save).

Version 1 stores ``{"schema_version": 1, "values": [...]}``; files saved by
ShapeSpace 0.1.0 hold bare JSON lists and still load.  Damage raises
``ShapeSpaceError`` (code ``corrupt_metadata``) naming the example.
"""
from __future__ import annotations

import math
import numbers

from ...core import blobs
from ...core.errors import ErrorCode
from ...core.result import ShapeSpaceError
from ...core.schema import Schema
from .. import storage
from .pose import settings

#: Suffix of the posed copy an example is sculpted on.
SCULPT_SUFFIX = "_sculpt"
#: The shape key holding weighted PSD's per-vertex result (the example keys stay at 0).
WPSD_KEY = "ShapeSpace_WPSD"
#: Name of the generated post-deformation modifier (at the end of the stack; see :mod:`.postdeform`).
MODIFIER = "ShapeSpace Post-Deform"

POSE_SCHEMA = blobs.EXAMPLE_POSE.schema
PSEUDO_POSE_SCHEMA = blobs.EXAMPLE_PSEUDO_POSE.schema
TARGET_VALUES_SCHEMA = blobs.EXAMPLE_TARGET_VALUES.schema
#: An example's final shape (:data:`core.blobs.EXAMPLE_FINAL_SHAPE`; see :mod:`.finalshape`).
FINAL_SHAPE_SCHEMA = blobs.EXAMPLE_FINAL_SHAPE.schema


#: Weighted PSD's distance for pose spaces made before ShapeSpace 0.2.0 (when Blended became the default).
#: Blender saves a property only once it is set, and those files never set it: with examples and no stored
#: distance, a pose space is one of them and keeps Skin Weighted.
LEGACY_WPSD_DISTANCE = "SKIN"


def wpsd_distance(st) -> str:
    """Weighted PSD's distance of the pose space ``st`` (``SHAPESPACE_PG_psd``): the stored one; unset, the
    default (Blended) for a pose space without examples and Skin Weighted for one made before 0.2.0."""
    if st.is_property_set("wpsd_distance") or not len(st.examples):
        return st.wpsd_distance
    return LEGACY_WPSD_DISTANCE


def pin_wpsd_distance(st) -> bool:
    """Store the pose space's distance explicitly (before its first example is added, on load and on save),
    so no later change of the default changes it.  Returns whether it wrote."""
    if st.is_property_set("wpsd_distance"):
        return False
    st.wpsd_distance = wpsd_distance(st)
    return True


def pin_settings(data) -> int:
    """Store explicitly every ShapeSpace setting whose default changed since the file was made, at the value
    the file meant: a pose space with examples and no stored distance was made before 0.2.0 and keeps Skin
    Weighted.  Runs after each load and before each save; linked (library) data is left untouched (it reads
    the same through :func:`wpsd_distance`).  Returns how many settings it wrote."""
    return sum(pin_wpsd_distance(ob.shapespace_psd) for ob in data.objects
               if ob.library is None and ob.type == "MESH" and len(ob.shapespace_psd.examples))


def is_post_deform_modifier(mod) -> bool:
    """True for the post-deformation modifier ShapeSpace generates (:mod:`.postdeform`)."""
    return mod.type == "NODES" and mod.name == MODIFIER


def find_example(obj, name: str):
    """The example called ``name`` (code ``missing_example`` when there is none)."""
    ex = settings(obj).examples.get(name)
    if ex is None:
        raise ShapeSpaceError(f"there is no example {name!r}", ErrorCode.MISSING_EXAMPLE)
    return ex


def _read_values(ex, attr: str, schema: Schema) -> list:
    values = storage.read_string_blob(ex, attr, schema)["values"]
    if not all(isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v) for v in values):
        raise ShapeSpaceError(f"damaged ShapeSpace data in {storage.where(ex, attr)}: "
                              "field 'values' must hold finite numbers only", ErrorCode.CORRUPT_METADATA)
    return [float(v) for v in values]


def _write_values(ex, attr: str, schema: Schema, values) -> None:
    storage.write_string_blob(ex, attr, schema, {"values": [float(v) for v in values]})


def example_pose(ex) -> list:
    """Where the example was sculpted (empty when never recorded)."""
    return _read_values(ex, "pose", POSE_SCHEMA)


def set_example_pose(ex, pose) -> None:
    _write_values(ex, "pose", POSE_SCHEMA, pose)


def pseudo_pose(ex) -> list:
    """Where a moved example is interpolated; empty when it was not moved."""
    return _read_values(ex, "pseudo_pose", PSEUDO_POSE_SCHEMA)


def set_pseudo_pose(ex, pose) -> None:
    """Move the example to ``pose``; an empty ``pose`` puts it back where it was sculpted."""
    _write_values(ex, "pseudo_pose", PSEUDO_POSE_SCHEMA, pose)


def interpolation_pose(ex) -> list:
    """Where the example is interpolated: its pseudo pose when moved, else its own pose."""
    return pseudo_pose(ex) or example_pose(ex)


def target_values(ex) -> list:
    """The driven targets' values recorded at the example (empty when never recorded)."""
    return _read_values(ex, "target_values", TARGET_VALUES_SCHEMA)


def set_target_values(ex, values) -> None:
    _write_values(ex, "target_values", TARGET_VALUES_SCHEMA, values)


def final_shape(ex) -> dict | None:
    """The example's stored final shape (:data:`FINAL_SHAPE_SCHEMA`), None when it has none."""
    if not ex.final_shape:
        return None
    return storage.read_string_blob(ex, "final_shape", FINAL_SHAPE_SCHEMA)


def set_final_shape(ex, data: dict | None) -> None:
    """Store (or, with None, clear) the example's final shape."""
    if data is None:
        ex.final_shape = ""
    else:
        storage.write_string_blob(ex, "final_shape", FINAL_SHAPE_SCHEMA, data)


def deleted_key(obj, name: str) -> ShapeSpaceError:
    """The error for an example whose corrective key was deleted (code ``missing_key``)."""
    return ShapeSpaceError(f"the corrective key {name!r} of {obj.name!r} was deleted: remove example {name!r} "
                           "(or undo the deletion)", ErrorCode.MISSING_KEY)


def check_examples(obj, need_keys: bool = True) -> None:
    """Refuse damaged pose-space data before anything is written, naming the example.

    Every example's stored pose, pseudo pose and target values must read (the functions above) and, with
    ``need_keys``, its corrective key must exist.
    """
    key = obj.data.shape_keys
    for ex in settings(obj).examples:
        example_pose(ex)
        pseudo_pose(ex)
        target_values(ex)
        if need_keys and (key is None or ex.name not in key.key_blocks):
            raise deleted_key(obj, ex.name)
