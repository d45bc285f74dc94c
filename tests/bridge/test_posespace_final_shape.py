"""Final-shape examples (issue #16 Build 1): stale correctives are flagged and re-inverted from the stored sculpt.

Every check is Blender's own depsgraph evaluation of the mesh at the example's pose.
"""
import numpy as np
import pytest
from mathutils import Vector

from blender_support import bpy, evaluated, import_file
from shapespace.bridge import meshes, skin
from shapespace.bridge.posespace import finalshape
from shapespace.core.blendshape import bounding_box_diagonal
from support import shared

TOL = 1e-5
#: (bone index, pose) of the examples: an arm and a leg, far apart on the mesh
POSES = ((5, (0.9, 0.3, 0.2, 0.1)), (12, (0.92, -0.2, 0.3, 0.1)))


def _cesium():
    import_file(shared("cesium_man", "CesiumMan.glb"))
    ob = bpy.data.objects["Cesium_Man"]
    arm = bpy.data.objects["Armature"]
    arm.animation_data.action = None
    for pb in arm.pose.bones:
        pb.rotation_mode = "QUATERNION"
        pb.rotation_quaternion = (1, 0, 0, 0)
    bpy.context.view_layer.objects.active = ob
    _BONES[:] = [arm.pose.bones[b].name for b, _ in POSES]
    return ob, arm


_BONES = []       # the posed bones' names (indices change when a bone is deleted)


def _rest_pose(arm):
    for pb in arm.pose.bones:
        pb.rotation_quaternion = (1, 0, 0, 0)
    bpy.context.view_layer.update()


def _pose(arm, k):
    _rest_pose(arm)
    arm.pose.bones[_BONES[k]].rotation_quaternion = POSES[k][1]
    bpy.context.view_layer.update()


def _sculpt(ob, example, seed, amount=0.01):
    """Push a smooth bump near the posed bone into the example's posed copy; the wanted positions (object space)."""
    copy = ob.shapespace_psd.examples[example].sculpt
    co = meshes.vertex_positions(copy.data).astype(np.float64)
    moved = np.abs(co - meshes.vertex_positions(ob.data)).max(axis=1)
    rng = np.random.default_rng(seed)
    centre = co[int(np.argmax(moved))]        # where the pose moved the mesh most: the joint's region
    size = bounding_box_diagonal(co)
    fall = np.exp(-np.sum((co - centre) ** 2, axis=1) / (0.05 * size) ** 2)
    co = co + amount * size * fall[:, None] * rng.normal(size=3)
    copy.data.vertices.foreach_set("co", co.astype(np.float32).ravel())
    copy.data.update()
    return meshes.to_local(ob, meshes.to_world(copy, co))


def _examples(ob, arm):
    """Two applied examples; returns their wanted posed positions."""
    wanted = []
    for k in range(len(POSES)):
        _pose(arm, k)
        assert bpy.ops.shapespace.psd_add_example() == {"FINISHED"}
        name = ob.shapespace_psd.examples[k].name
        wanted.append(_sculpt(ob, name, k + 1))
        assert bpy.ops.shapespace.psd_apply_example(remove_copy=True) == {"FINISHED"}
    _rest_pose(arm)
    return wanted


def _at_example(ob, arm, k):
    """Blender's evaluation at example k's pose with only its corrective on, and with none (p, 3) each."""
    _pose(arm, k)
    blocks = ob.data.shape_keys.key_blocks
    names = [ex.name for ex in ob.shapespace_psd.examples]
    for n in names:
        blocks[n].value = 0.0
    plain = evaluated(ob)
    blocks[names[k]].value = 1.0
    got = evaluated(ob)
    blocks[names[k]].value = 0.0
    return got, plain


def _assert_sculpt_restored(ob, arm, wanted):
    """At each example's pose its sculpted vertices are where they were sculpted, the rest follow the rig."""
    for k, want in enumerate(wanted):
        idx, _ = finalshape.final_shape_positions(ob, ob.shapespace_psd.examples[k].name)
        got, plain = _at_example(ob, arm, k)
        expected = plain.copy()
        expected[idx] = want[idx]
        size = bounding_box_diagonal(want)
        assert len(idx) > 20
        assert np.abs(got - expected).max() / size < TOL
        assert np.abs(got[idx] - want[idx]).max() / size < TOL
    _rest_pose(arm)


def _vertex_weight(ob, v):
    g = max(ob.data.vertices[v].groups, key=lambda g: g.weight)
    return ob.vertex_groups[g.group], g.weight


def _reweight(ob, idx):
    """Re-weight the vertices of ``idx`` that two bones share: their strongest group's weight × 0.2."""
    count = 0
    for i in idx:
        groups = ob.data.vertices[int(i)].groups
        if len(groups) > 1 and sorted(g.weight for g in groups)[-2] > 0.05:
            group, w = _vertex_weight(ob, int(i))
            group.add([int(i)], w * 0.2, "REPLACE")
            count += 1
    assert count


def _stale(ob):
    return {name: (code, message) for name, code, message in finalshape.stale_examples(ob)}


def _set_rest(arm, bone, roll=0.3, tail=(0.0, 0.0, 0.02)):
    bpy.context.view_layer.objects.active = arm
    bpy.ops.object.mode_set(mode="EDIT")
    eb = arm.data.edit_bones[bone]
    eb.roll += roll
    eb.tail = eb.tail + Vector(tail)
    bpy.ops.object.mode_set(mode="OBJECT")


def test_weight_and_rest_pose_changes_are_flagged_and_reinvert_returns_to_the_sculpt(registered, tmp_path):
    ob, arm = _cesium()
    wanted = _examples(ob, arm)
    names = [ex.name for ex in ob.shapespace_psd.examples]
    _assert_sculpt_restored(ob, arm, wanted)            # as applied
    assert _stale(ob) == {}
    idx0, _ = finalshape.final_shape_positions(ob, names[0])
    idx1, _ = finalshape.final_shape_positions(ob, names[1])
    assert not set(idx0) & set(idx1)

    # re-weight a vertex example 0 sculpted: only example 0 is flagged, by name, saying why
    _reweight(ob, idx0)
    stale = _stale(ob)
    assert set(stale) == {names[0]}
    assert stale[names[0]][0] == "stale_example" and "skin weights" in stale[names[0]][1]

    # move the rest pose of a bone that moves example 1's vertices: example 1 is flagged too
    bone = sorted(set(finalshape.final_shape(ob.shapespace_psd.examples[1])["fingerprint"]["bones"])
                  - set(finalshape.final_shape(ob.shapespace_psd.examples[0])["fingerprint"]["bones"]))[-1]
    _set_rest(arm, bone)
    bpy.context.view_layer.objects.active = ob
    stale = _stale(ob)
    assert set(stale) == set(names)
    assert f"rest pose of bone {bone!r}" in stale[names[1]][1]

    # the stale correctives no longer give the sculpt …
    got, _ = _at_example(ob, arm, 0)
    assert np.abs(got[idx0] - wanted[0][idx0]).max() / bounding_box_diagonal(wanted[0]) > 10 * TOL
    _rest_pose(arm)
    # … re-invert one, then all: every example returns to its sculpt, nothing stale, pose left as it was
    before = [tuple(pb.rotation_quaternion) for pb in arm.pose.bones]
    ob.shapespace_psd.active_example = 1
    assert bpy.ops.shapespace.reinvert_example() == {"FINISHED"}
    assert set(_stale(ob)) == {names[0]}
    assert bpy.ops.shapespace.reinvert_all() == {"FINISHED"}
    assert [tuple(pb.rotation_quaternion) for pb in arm.pose.bones] == before
    assert _stale(ob) == {}
    _assert_sculpt_restored(ob, arm, wanted)

    # the final shapes survive save and reload, compactly (float32, only the sculpted vertices)
    path = str(tmp_path / "final.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)
    ob, arm = bpy.data.objects["Cesium_Man"], bpy.data.objects["Armature"]
    for k, ex in enumerate(ob.shapespace_psd.examples):
        idx, pos = finalshape.final_shape_positions(ob, ex.name)
        assert len(ex.final_shape) < 24 * len(idx) + 40 * 16 * len(arm.pose.bones) + 4000
        assert np.abs(pos - wanted[k][idx]).max() / bounding_box_diagonal(wanted[k]) < 1e-6
    assert _stale(ob) == {}
    _assert_sculpt_restored(ob, arm, wanted)


def test_weights_changed_where_no_example_sculpted_flag_nothing(registered):
    ob, arm = _cesium()
    _examples(ob, arm)
    touched = set()
    for ex in ob.shapespace_psd.examples:
        touched |= set(finalshape.final_shape_positions(ob, ex.name)[0].tolist())
    free = [v for v in range(len(ob.data.vertices)) if v not in touched and len(ob.data.vertices[v].groups)]
    for v in free[:: max(1, len(free) // 50)]:
        group, w = _vertex_weight(ob, v)
        group.add([v], w * 0.5, "REPLACE")
    assert finalshape.stale_examples(ob) == []


def test_deleted_bone_is_flagged_and_reinvert_refuses_naming_it(registered):
    ob, arm = _cesium()
    wanted = _examples(ob, arm)
    name = ob.shapespace_psd.examples[0].name
    bones = finalshape.final_shape(ob.shapespace_psd.examples[0])["fingerprint"]["bones"]
    other = finalshape.final_shape(ob.shapespace_psd.examples[1])["fingerprint"]["bones"]
    leaves = [b for b in bones if b not in other and not arm.data.bones[b].children]
    bone = leaves[0]
    bpy.context.view_layer.objects.active = arm
    bpy.ops.object.mode_set(mode="EDIT")
    arm.data.edit_bones.remove(arm.data.edit_bones[bone])
    bpy.ops.object.mode_set(mode="OBJECT")
    bpy.context.view_layer.objects.active = ob
    stale = _stale(ob)
    assert stale[name][0] == "missing_bone" and f"bone {bone!r} was deleted" in stale[name][1]
    key_before = np.array([tuple(d.co) for d in ob.data.shape_keys.key_blocks[name].data])
    ob.shapespace_psd.active_example = 0
    with pytest.raises(RuntimeError, match=f"{name}.*{bone}"):
        bpy.ops.shapespace.reinvert_example()
    with pytest.raises(RuntimeError, match=bone):
        bpy.ops.shapespace.reinvert_all()          # all or nothing: example 1 is not rewritten either
    after = np.array([tuple(d.co) for d in ob.data.shape_keys.key_blocks[name].data])
    assert np.array_equal(key_before, after)
    # the other example re-inverts on its own
    ob.shapespace_psd.active_example = 1
    assert bpy.ops.shapespace.reinvert_example() == {"FINISHED"}
    idx, _ = finalshape.final_shape_positions(ob, ob.shapespace_psd.examples[1].name)
    got, _ = _at_example(ob, arm, 1)
    assert np.abs(got[idx] - wanted[1][idx]).max() / bounding_box_diagonal(wanted[1]) < TOL


def test_example_from_0_1_0_captures_its_final_shape_from_the_corrective(registered):
    ob, arm = _cesium()
    _examples(ob, arm)
    ex = ob.shapespace_psd.examples[0]
    ex.final_shape = ""                                    # as ShapeSpace 0.1.0 saved it
    stale = _stale(ob)
    assert stale[ex.name][0] == "no_final_shape" and "capture" in stale[ex.name][1]
    ob.shapespace_psd.active_example = 0
    with pytest.raises(RuntimeError, match="no final shape"):
        bpy.ops.shapespace.reinvert_example()
    _pose(arm, 1)                                           # not at the example's pose: refused
    with pytest.raises(RuntimeError, match="pose the rig at example"):
        bpy.ops.shapespace.capture_final_shape()
    assert ex.final_shape == ""
    _pose(arm, 0)
    got_before, _ = _at_example(ob, arm, 0)                # today's corrective's posed result
    assert bpy.ops.shapespace.capture_final_shape() == {"FINISHED"}
    with pytest.raises(RuntimeError, match="already"):
        bpy.ops.shapespace.capture_final_shape()
    assert _stale(ob) == {}
    idx, pos = finalshape.final_shape_positions(ob, ex.name)
    size = bounding_box_diagonal(got_before)
    assert np.abs(pos - got_before[idx]).max() / size < 1e-6
    _reweight(ob, idx)
    assert set(_stale(ob)) == {ex.name}
    _rest_pose(arm)
    assert bpy.ops.shapespace.reinvert_all() == {"FINISHED"}
    got, _ = _at_example(ob, arm, 0)
    assert np.abs(got[idx] - got_before[idx]).max() / size < TOL


def test_damaged_final_shape_is_named(registered):
    ob, arm = _cesium()
    _examples(ob, arm)
    ex = ob.shapespace_psd.examples[1]
    ex.final_shape = '{"schema_version": 1, "vertex_count": 3}'
    stale = _stale(ob)
    assert stale[ex.name][0] == "corrupt_metadata" and ex.name in stale[ex.name][1]
    ob.shapespace_psd.active_example = 1
    with pytest.raises(RuntimeError, match="damaged ShapeSpace data"):
        bpy.ops.shapespace.reinvert_example()
    assert skin.armature_modifiers(ob)


def test_panel_names_the_stale_examples_and_offers_reinvert_and_capture(registered):
    from test_panels import _draw_all
    ob, arm = _cesium()
    _examples(ob, arm)
    names = [ex.name for ex in ob.shapespace_psd.examples]
    log = _draw_all(bpy.context)["SHAPESPACE_PT_correctives"]
    assert ("operator", "shapespace.reinvert_all") not in log
    assert ("operator", "shapespace.push_sculpt_masked") in log
    _reweight(ob, finalshape.final_shape_positions(ob, names[0])[0])
    ob.shapespace_psd.examples[1].final_shape = ""
    finalshape.STALE_CHECKS.clear()                 # the panel re-checks at most once a second
    log = _draw_all(bpy.context)["SHAPESPACE_PT_correctives"]
    labels = [text for kind, text in log if kind == "label"]
    assert any(t.startswith(f"{names[0]}: ") and "skin weights" in t for t in labels)
    assert any(t.startswith(f"{names[1]}: no final shape") for t in labels)
    assert ("operator", "shapespace.reinvert_example") in log and ("operator", "shapespace.reinvert_all") in log
    assert ("operator", "shapespace.capture_final_shape") in log


def test_switching_to_dual_quaternions_flags_the_modifier_and_reinvert_restores(registered):
    ob, arm = _cesium()
    wanted = _examples(ob, arm)
    names = [ex.name for ex in ob.shapespace_psd.examples]
    assert _stale(ob) == {}                                   # the digest is stable across evaluations
    mod = skin.armature_modifiers(ob)[0]
    mod.use_deform_preserve_volume = True
    stale = _stale(ob)
    assert set(stale) == set(names) and all(f"modifier {mod.name!r} changed" in m for _, m in stale.values())
    assert bpy.ops.shapespace.reinvert_all() == {"FINISHED"}
    assert _stale(ob) == {}
    _assert_sculpt_restored(ob, arm, wanted)
