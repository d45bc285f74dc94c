"""The correctives' shape keys: reading them and the checks every pose-space verb makes first.

Each example's corrective is a shape key of the example's name holding its rest-space displacement from the
basis; weighted PSD's result is one more key (:data:`.stored.WPSD_KEY`).
"""
from __future__ import annotations

import numpy as np

from ...core.errors import ErrorCode
from ...core.result import ShapeSpaceError
from .. import shapekeys
from ..arrays import read_float
from .pose import settings
from .stored import WPSD_KEY, deleted_key


def example_keys(obj) -> set:
    """Names of the shape keys the pose-space correctives own (the examples' and weighted PSD's)."""
    return {ex.name for ex in settings(obj).examples} | {WPSD_KEY}


def check_not_editing(obj) -> None:
    """Refuse a mesh in Edit Mode: its mesh and shape-key data are stale until Edit Mode is left, and what
    ShapeSpace wrote would be overwritten then (code ``mode``)."""
    if obj.mode == "EDIT":
        raise ShapeSpaceError(f"{obj.name!r} is in Edit Mode: leave Edit Mode first (its mesh data is not up "
                              "to date until then)", ErrorCode.MODE)


def shape_keys(obj):
    """The mesh's ``Key`` datablock; refused naming the examples' keys when every shape key was deleted."""
    key = obj.data.shape_keys
    if key is None:
        names = [ex.name for ex in settings(obj).examples]
        if names:
            raise deleted_key(obj, names[0])
        raise ShapeSpaceError(f"{obj.name!r} has no shape keys", ErrorCode.NO_SHAPE_KEYS)
    return key


def check_finite_positions(positions: np.ndarray, what: str) -> None:
    """Refuse NaN/inf positions (p, 3), naming ``what``, the vertex and the axis (code ``non_finite``)."""
    bad = ~np.isfinite(positions)
    if bad.any():
        v, axis = (int(i) for i in np.argwhere(bad)[0])
        raise ShapeSpaceError(f"{what} has a non-finite coordinate ({'xyz'[axis]} = {positions[v, axis]}) at "
                              f"vertex {v}", ErrorCode.NON_FINITE)


def key_positions(obj, kb) -> np.ndarray:
    """A shape key's positions (p, 3), float64; refused when its vertex count or a coordinate is wrong."""
    p = len(obj.data.vertices)
    if len(kb.data) != p:
        raise ShapeSpaceError(f"shape key {kb.name!r} of {obj.name!r} has {len(kb.data)} vertices, the mesh has "
                              f"{p}: the topology changed after the key was made", ErrorCode.VERTEX_COUNT_MISMATCH)
    co = read_float(kb.data, "co", 3).astype(np.float64)
    check_finite_positions(co, f"shape key {kb.name!r} of {obj.name!r}")
    return co


def basis_positions(obj) -> np.ndarray:
    """The reference key's positions (p, 3), float64 (refused when non-finite, naming the key and vertex)."""
    return key_positions(obj, shape_keys(obj).reference_key)


def example_correctives(obj, examples, missing_as_zero: bool = False) -> np.ndarray:
    """Rest-space correctives (key minus basis) of ``examples``, shape (K, p, 3)."""
    key = shape_keys(obj)
    basis = basis_positions(obj)
    out = []
    for ex in examples:
        if ex.name in key.key_blocks:
            out.append(key_positions(obj, key.key_blocks[ex.name]) - basis)
        elif missing_as_zero:
            out.append(np.zeros_like(basis))
        else:
            raise deleted_key(obj, ex.name)
    return np.stack(out) if out else np.zeros((0,) + basis.shape)


def pre_armature_positions(obj) -> np.ndarray:
    """Mesh positions before the Armature modifier, without the pose-space correctives (object space)."""
    model = shapekeys.read_blendshape_model(obj)
    w = model.values.copy()
    for name in example_keys(obj):
        if name in model.names:
            w[model.index(name)] = 0.0
    return model.evaluate(w)


def check_topology(obj) -> None:
    """Refuse meshes whose shape keys no longer match the mesh (the first error found)."""
    if obj.data.shape_keys is not None:
        errors = [i for i in shapekeys.check_shape_keys(obj) if i.severity == "error" and i.code != "no_targets"]
        if errors:
            raise ShapeSpaceError(errors[0].message, errors[0].code)


def new_corrective_key(obj, name: str):
    """An empty corrective key (at 0, sliders wide open: cardinal weights may leave [0, 1])."""
    if obj.data.shape_keys is None:
        obj.shape_key_add(name="Basis", from_mix=False)
    kb = obj.shape_key_add(name=name, from_mix=False)
    kb.slider_min, kb.slider_max = -10.0, 10.0
    kb.value = 0.0
    return kb
