"""One sculpt, many keys (issue #16 Build 2): masked parts add up to the sculpt; mirrors; uncovered vertices.

Checked with Blender's own depsgraph evaluation of the posed mesh.
"""
import re

import numpy as np
import pytest
from scipy.spatial import cKDTree

from blender_support import bpy, evaluated
from shapespace.bridge import meshes
from shapespace.core.blendshape import bounding_box_diagonal

TOL = 1e-5


def _smooth(t):
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3 - 2 * t)


def _set_group(ob, name, weights):
    g = ob.vertex_groups.new(name=name)
    for v, w in enumerate(weights):
        if w > 0:
            g.add([v], float(w), "REPLACE")


def _rig():
    """A mesh symmetric across X (ellipsoid along X) skinned to root / arm.L / arm.R; masks mask.L, mask.R
    overlapping around the centre with weights that do not add up to 1 there."""
    bpy.ops.mesh.primitive_uv_sphere_add(segments=32, ring_count=16, radius=1.0)
    ob = bpy.context.active_object
    ob.name = "Body"
    co = meshes.vertex_positions(ob.data).astype(np.float64) * [2.0, 1.0, 1.0]
    ob.data.vertices.foreach_set("co", co.astype(np.float32).ravel())
    ob.data.update()
    arm_data = bpy.data.armatures.new("Rig")
    arm = bpy.data.objects.new("Rig", arm_data)
    bpy.context.scene.collection.objects.link(arm)
    bpy.context.view_layer.objects.active = arm
    bpy.ops.object.mode_set(mode="EDIT")
    root = arm_data.edit_bones.new("root")
    root.head, root.tail = (0, 0, 0), (0, 0, 0.5)
    for side, s in (("L", 1.0), ("R", -1.0)):
        b = arm_data.edit_bones.new(f"arm.{side}")
        b.head, b.tail = (0.6 * s, 0, 0), (2.0 * s, 0, 0)
        b.parent = root
    bpy.ops.object.mode_set(mode="OBJECT")
    x = co[:, 0]
    wl, wr = _smooth((x - 0.4) / 0.8), _smooth((-x - 0.4) / 0.8)
    _set_group(ob, "root", 1.0 - wl - wr)
    _set_group(ob, "arm.L", wl)
    _set_group(ob, "arm.R", wr)
    _set_group(ob, "mask.L", _smooth((x + 0.5) / 0.8))
    _set_group(ob, "mask.R", 0.8 * _smooth((0.5 - x) / 0.8))
    mod = ob.modifiers.new("Armature", "ARMATURE")
    mod.object = arm
    for pb in arm.pose.bones:
        pb.rotation_mode = "QUATERNION"
    arm.pose.bones["arm.L"].rotation_quaternion = (0.95, 0.0, 0.2, 0.25)
    arm.pose.bones["arm.R"].rotation_quaternion = (0.93, 0.1, -0.2, 0.3)
    bpy.context.view_layer.update()
    bpy.context.view_layer.objects.active = ob
    ob.select_set(True)
    return ob, arm


def _sculpt(ob, centres, amount=0.03):
    """Bumps at ``centres`` (x positions on the +y side) in the example's posed copy; wanted positions."""
    copy = ob.shapespace_psd.examples[0].sculpt
    co = meshes.vertex_positions(copy.data).astype(np.float64)
    rest = meshes.vertex_positions(ob.data).astype(np.float64)
    size = bounding_box_diagonal(co)
    out = co.copy()
    for k, cx in enumerate(centres):
        fall = np.exp(-np.sum((rest - [cx, 1.0, 0.0]) ** 2, axis=1) / 0.35 ** 2)
        fall[fall < 1e-3] = 0.0
        out += amount * size * fall[:, None] * np.array([0.3 * (k + 1), 1.0, -0.5])
    copy.data.vertices.foreach_set("co", out.astype(np.float32).ravel())
    copy.data.update()
    return meshes.to_local(ob, meshes.to_world(copy, out))


def _with_keys(ob, on):
    """Blender's evaluation with only the keys ``on`` at 1 (every other key at 0)."""
    blocks = ob.data.shape_keys.key_blocks
    saved = {kb.name: kb.value for kb in blocks}
    for kb in blocks:
        kb.value = 1.0 if kb.name in on else 0.0
    got = evaluated(ob)
    for kb in blocks:
        kb.value = saved[kb.name]
    return got


def _weights(ob, group):
    g = ob.vertex_groups[group].index
    return np.array([sum(e.weight for e in v.groups if e.group == g) for v in ob.data.vertices])


def test_masked_parts_add_up_to_the_sculpt_at_the_pose(registered):
    ob, arm = _rig()
    assert bpy.ops.shapespace.psd_add_example() == {"FINISHED"}
    wanted = _sculpt(ob, (-1.4, 0.0, 1.4))               # both arms and the centre, where the masks overlap
    assert bpy.ops.shapespace.push_sculpt_masked(groups="mask.L, mask.R") == {"FINISHED"}
    parts = ["PSD_01.mask.L", "PSD_01.mask.R"]
    assert all(p in ob.data.shape_keys.key_blocks for p in parts)
    size = bounding_box_diagonal(wanted)
    got = _with_keys(ob, parts)
    assert np.abs(got - wanted).max() / size < TOL
    # each part lives inside its own mask, and both share the overlap smoothly
    plain = _with_keys(ob, [])
    for part, group in zip(parts, ("mask.L", "mask.R")):
        moved = np.abs(_with_keys(ob, [part]) - plain).max(axis=1)
        assert moved[_weights(ob, group) == 0].max() < 1e-6 * size
    overlap = (_weights(ob, "mask.L") > 0) & (_weights(ob, "mask.R") > 0) & (np.abs(wanted - plain).max(axis=1) > 1e-3)
    assert overlap.sum() > 5
    left = np.abs(_with_keys(ob, [parts[0]]) - plain)[overlap].max(axis=1)
    right = np.abs(_with_keys(ob, [parts[1]]) - plain)[overlap].max(axis=1)
    assert (left > 0).all() and (right > 0).all()
    # the parts are plain keys, left at 0 for the rigger to drive
    assert ob.data.shape_keys.key_blocks[parts[0]].value == 0.0


def test_uncovered_vertices_are_refused_by_index_or_kept_in_a_remainder(registered):
    ob, arm = _rig()
    assert bpy.ops.shapespace.psd_add_example() == {"FINISHED"}
    wanted = _sculpt(ob, (-1.4, 1.4))
    keys_before = [kb.name for kb in ob.data.shape_keys.key_blocks]
    with pytest.raises(RuntimeError, match=r"do not cover (\d+) sculpted vertices") as err:
        bpy.ops.shapespace.push_sculpt_masked(groups="mask.L")
    assert [kb.name for kb in ob.data.shape_keys.key_blocks] == keys_before
    message = str(err.value)
    count = int(re.search(r"do not cover (\d+)", message).group(1))
    listed = [int(v) for v in re.search(r"vertices \(([\d, ]+)", message).group(1).split(",")]
    plain = _with_keys(ob, [])
    moved = np.abs(wanted - plain).max(axis=1) > 1e-6 * bounding_box_diagonal(wanted)
    mask = _weights(ob, "mask.L")
    assert count == int((moved & (mask == 0)).sum()) and count > 0
    assert all(mask[v] == 0 and moved[v] for v in listed)
    with pytest.raises(RuntimeError, match="no vertex group 'nope'"):
        bpy.ops.shapespace.push_sculpt_masked(groups="mask.L, nope")
    assert bpy.ops.shapespace.push_sculpt_masked(groups="mask.L", remainder=True) == {"FINISHED"}
    got = _with_keys(ob, ["PSD_01.mask.L", "PSD_01.remainder"])
    assert np.abs(got - wanted).max() / bounding_box_diagonal(wanted) < TOL
    rem = np.abs(_with_keys(ob, ["PSD_01.remainder"]) - plain).max(axis=1)
    assert rem[mask > 0].max() < 1e-6 * bounding_box_diagonal(wanted)
    # pushing again without Replace does not overwrite
    with pytest.raises(RuntimeError, match="exists already"):
        bpy.ops.shapespace.push_sculpt_masked(groups="mask.L", remainder=True)


def test_mirror_part_is_the_mirrored_sculpt(registered):
    ob, arm = _rig()
    arm.pose.bones["arm.R"].rotation_quaternion = (1, 0, 0, 0)
    arm.pose.bones["arm.L"].rotation_quaternion = (1, 0, 0, 0)
    bpy.context.view_layer.update()
    arm.pose.bones["arm.L"].rotation_quaternion = (0.95, 0.0, 0.2, 0.25)
    bpy.context.view_layer.update()
    assert bpy.ops.shapespace.psd_add_example() == {"FINISHED"}
    wanted = _sculpt(ob, (1.4,))                          # the left arm only
    assert bpy.ops.shapespace.push_sculpt_masked(groups="mask.L", mirror=True) == {"FINISHED"}
    blocks = ob.data.shape_keys.key_blocks
    assert "PSD_01.mask.L" in blocks and "PSD_01.mask.R" in blocks
    size = bounding_box_diagonal(wanted)
    assert np.abs(_with_keys(ob, ["PSD_01.mask.L"]) - wanted).max() / size < TOL
    # at the rest pose the mirrored key moves each vertex as the left part moves its mirror vertex, x flipped
    arm.pose.bones["arm.L"].rotation_quaternion = (1, 0, 0, 0)
    bpy.context.view_layer.update()
    plain = _with_keys(ob, [])
    left = _with_keys(ob, ["PSD_01.mask.L"]) - plain
    right = _with_keys(ob, ["PSD_01.mask.R"]) - plain
    rest = meshes.vertex_positions(ob.data).astype(np.float64)
    dist, partner = cKDTree(rest).query(rest * [-1.0, 1.0, 1.0])
    assert dist.max() < 1e-5
    assert np.abs(left).max() > 1e-3 * size
    assert np.abs(right - left[partner] * [-1.0, 1.0, 1.0]).max() / size < TOL
    # both sides' masks with Mirror would make the same key twice: refused
    with pytest.raises(RuntimeError, match="made twice"):
        bpy.ops.shapespace.push_sculpt_masked(groups="mask.L, mask.R", mirror=True, replace=True)
