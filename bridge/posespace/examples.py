"""Pose-space examples in Blender: recording, moving and removing them.

An example is a pose (:mod:`.stored`), a corrective shape key of the same
name (rest-space displacement from the basis, read through :mod:`.correctives`)
and, until applied, a posed copy of the mesh to sculpt on.
"""
from __future__ import annotations

import bpy

from ...core.errors import ErrorCode
from ...core.posespace.readers import PoseReader
from ...core.result import ShapeSpaceError
from .. import meshes
from .correctives import basis_positions, check_finite_positions, check_not_editing, check_topology, new_corrective_key
from .pose import add_readers, armature_of, default_readers, read_pose, readers, settings
from .postdeform import remove_post_deform
from .stored import (
    SCULPT_SUFFIX,
    check_examples,
    find_example,
    pin_wpsd_distance,
    set_example_pose,
    set_pseudo_pose,
    set_target_values,
)
from .targets import read_targets


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
