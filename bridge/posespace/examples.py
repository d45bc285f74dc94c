"""Pose-space examples in Blender: recording, moving and removing them, and reading their correctives.

An example is a pose (:mod:`.stored`), a corrective shape key of the same
name (rest-space displacement from the basis) and, until applied, a posed
copy of the mesh to sculpt on.
"""
from __future__ import annotations

import bpy
import numpy as np

from ...core.errors import ErrorCode
from ...core.result import ShapeSpaceError
from .. import shapekeys
from ..arrays import read_float
from .pose import add_default_readers, read_pose, settings
from .stored import SCULPT_SUFFIX, WPSD_KEY, find_example, set_example_pose, set_pseudo_pose, set_target_values
from .targets import read_targets


def example_keys(obj) -> set:
    """Names of the shape keys the pose-space correctives own (the examples' and weighted PSD's)."""
    return {ex.name for ex in settings(obj).examples} | {WPSD_KEY}


def basis_positions(obj) -> np.ndarray:
    """The reference key's positions (p, 3), float64."""
    return read_float(obj.data.shape_keys.reference_key.data, "co", 3).astype(np.float64)


def example_correctives(obj, examples, missing_as_zero: bool = False) -> np.ndarray:
    """Rest-space correctives (key minus basis) of ``examples``, shape (K, p, 3)."""
    key = obj.data.shape_keys
    basis = basis_positions(obj)
    out = []
    for ex in examples:
        if ex.name in key.key_blocks:
            out.append(read_float(key.key_blocks[ex.name].data, "co", 3).astype(np.float64) - basis)
        elif missing_as_zero:
            out.append(np.zeros_like(basis))
        else:
            raise ShapeSpaceError(f"the corrective key {ex.name!r} was deleted", ErrorCode.MISSING_KEY)
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


def add_example(obj, name: str = None, make_sculpt_copy: bool = True) -> str:
    """Record the current pose as a new example, create its (empty) corrective key and a posed copy to sculpt.

    An empty pose space first gets a rotation reader for every posed deforming bone.  Returns the
    example's name (its key's name).
    """
    check_topology(obj)
    st = settings(obj)
    if not len(st.readers) and not add_default_readers(obj):
        raise ShapeSpaceError("pose the rig away from its rest pose first (no bone is rotated), or add "
                              "pose-space readers by hand", ErrorCode.NO_READERS)
    pose = read_pose(obj)
    kb = new_corrective_key(obj, name or f"PSD_{len(st.examples) + 1:02d}")
    ex = st.examples.add()
    ex.name = kb.name
    set_example_pose(ex, pose)
    set_target_values(ex, read_targets(obj))
    st.active_example = len(st.examples) - 1
    st.revision += 1
    copy = make_sculpt_copy and posed_copy(obj, kb.name + SCULPT_SUFFIX)
    if copy:
        ex.sculpt = copy
    return ex.name


def posed_copy(obj, name: str):
    """A plain mesh object holding ``obj``'s evaluated (posed) surface, at the same place, for sculpting."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    depsgraph.update()
    ob_eval = obj.evaluated_get(depsgraph)
    mesh = bpy.data.meshes.new_from_object(ob_eval)
    mesh.name = name
    copy = bpy.data.objects.new(name, mesh)
    copy.matrix_world = obj.matrix_world.copy()
    for coll in obj.users_collection:
        coll.objects.link(copy)
    return copy


def remove_sculpt_copy(obj, example_name: str) -> bool:
    """Delete the example's posed copy; False when it has none."""
    ex = find_example(obj, example_name)
    if ex.sculpt is None:
        return False
    bpy.data.objects.remove(ex.sculpt)
    return True


def remove_example(obj, example_name: str) -> str:
    """Delete an example, its corrective shape key and its posed copy; returns its name."""
    st = settings(obj)
    find_example(obj, example_name)
    remove_sculpt_copy(obj, example_name)
    key = obj.data.shape_keys
    if key is not None and example_name in key.key_blocks:
        obj.shape_key_remove(key.key_blocks[example_name])
    st.examples.remove(st.examples.find(example_name))
    st.active_example = max(0, min(st.active_example, len(st.examples) - 1))
    st.revision += 1
    return example_name


def move_example(obj, example_name: str, reset: bool = False) -> None:
    """Shape-by-Example pseudo-example: interpolate this sculpt at the current pose (or back where sculpted)."""
    st = settings(obj)
    ex = find_example(obj, example_name)
    set_pseudo_pose(ex, [] if reset else read_pose(obj))
    st.revision += 1
