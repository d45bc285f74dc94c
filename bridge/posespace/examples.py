"""Pose-space examples in Blender: recording, moving and removing them, and reading their correctives.

An example is a pose (:mod:`.stored`), a corrective shape key of the same
name (rest-space displacement from the basis) and, until applied, a posed
copy of the mesh to sculpt on.
"""
from __future__ import annotations

import bpy
import numpy as np

from ...core.errors import ErrorCode
from ...core.posespace.readers import PoseReader
from ...core.result import ShapeSpaceError
from .. import meshes, shapekeys
from ..arrays import read_float
from .pose import add_readers, armature_of, default_readers, read_pose, readers, settings
from .stored import (SCULPT_SUFFIX, WPSD_KEY, check_examples, deleted_key, find_example, pin_wpsd_distance,
                     set_example_pose, set_pseudo_pose, set_target_values)
from .targets import read_targets


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


def _new_pose_space(obj) -> list:
    """Bones for the default rotation readers when the pose space is empty (none when it has readers)."""
    if len(settings(obj).readers):
        return []
    bones = default_readers(obj)
    if not bones:
        raise ShapeSpaceError("pose the rig away from its rest pose first (no bone is rotated), or add "
                              "pose-space readers by hand", ErrorCode.NO_READERS)
    return bones


def add_example(obj, name: str = None, make_sculpt_copy: bool = True) -> str:
    """Record the current pose as a new example, create its (empty) corrective key and a posed copy to sculpt.

    An empty pose space first gets a rotation reader for every posed deforming bone.  Everything is read and
    checked before anything is written.  Returns the example's name (its key's name).
    """
    check_not_editing(obj)
    check_topology(obj)
    check_examples(obj)
    if obj.data.shape_keys is not None:
        basis_positions(obj)
    else:
        check_finite_positions(meshes.vertex_positions(obj.data), f"mesh {obj.name!r}")
    st = settings(obj)
    bones = _new_pose_space(obj)
    rs = [PoseReader("rotation", b, 1.0) for b in bones] if bones else None
    pose = read_pose(obj, rs)
    targets = read_targets(obj)
    add_readers(obj, bones)
    kb = new_corrective_key(obj, name or f"PSD_{len(st.examples) + 1:02d}")
    pin_wpsd_distance(st)
    ex = st.examples.add()
    ex.name = kb.name
    set_example_pose(ex, pose)
    set_target_values(ex, targets)
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
    """Delete an example, its corrective shape key and its posed copy; returns its name.

    Works on damaged examples too (it is how they are cleaned up)."""
    check_not_editing(obj)
    st = settings(obj)
    find_example(obj, example_name)
    remove_sculpt_copy(obj, example_name)
    key = obj.data.shape_keys
    if key is not None and example_name in key.key_blocks:
        obj.shape_key_remove(key.key_blocks[example_name])
    post_deform = find_example(obj, example_name).post_deform
    st.examples.remove(st.examples.find(example_name))
    if post_deform:
        from .postdeform import remove_post_deform
        remove_post_deform(obj, example_name)
    st.active_example = max(0, min(st.active_example, len(st.examples) - 1))
    st.revision += 1
    return example_name


def move_example(obj, example_name: str, reset: bool = False) -> None:
    """Shape-by-Example pseudo-example: interpolate this sculpt at the current pose (or back where sculpted)."""
    check_not_editing(obj)
    st = settings(obj)
    ex = find_example(obj, example_name)
    check_examples(obj)
    pose = [] if reset else read_pose(obj)
    set_pseudo_pose(ex, pose)
    st.revision += 1


def problem(obj) -> str:
    """The first thing that stops ``obj``'s pose-space correctives from working, as one line ('' when none).

    Why Live Preview last stopped, damaged stored data, deleted corrective keys, readers naming missing
    bones.  Cheap enough for a panel's draw; never raises a ShapeSpaceError.
    """
    st = settings(obj)
    if st.preview_message and not st.live_preview:
        return f"Live Preview stopped: {st.preview_message}"
    try:
        check_examples(obj)
        rs = readers(obj)
        arm = armature_of(obj) if any(r.is_bone for r in rs) else None
        for r in rs:
            if r.is_bone and (arm is None or r.source not in arm.pose.bones):
                where = f"in {arm.name!r}" if arm is not None else "(no armature)"
                return f"pose-space reader bone {r.source!r} does not exist {where}: fix or remove the reader"
    except ShapeSpaceError as exc:
        return str(exc)
    return ""
