"""Pose-space correctives in Blender: add example, sculpt, apply (inversion), interpolate, preview, bake; and
under bad scenes (issue #10): deleted shape keys (r17), switching methods, the point-cache path (r31), NaN inputs
(r18), Edit Mode (r07), damaged stored data (r21), progress.

Every refusal is one line naming the culprit and leaves the file exactly as it was; the live preview never
prints a traceback: it stops previewing the mesh and says why once.
"""
import json
import os

import numpy as np
import pytest

from blender_support import OPERATOR_CALLS, SS, blend_fingerprint, bpy, classify_operator_call, evaluated, import_file
from blender_support import RecordingLayout as Layout
from shapespace.bridge import meshes, posespace, skin
from shapespace.core.blendshape import bounding_box_diagonal
from shapespace.core.pointcache import read_pc2
from shapespace.core.result import ShapeSpaceError
from shapespace.ui import posespace_preview
from support import shared

TOL = 1e-5


def _cesium(dqs=False):
    import_file(shared("cesium_man", "CesiumMan.glb"))
    ob = bpy.data.objects["Cesium_Man"]
    arm = bpy.data.objects["Armature"]
    arm.animation_data.action = None
    for pb in arm.pose.bones:
        pb.rotation_mode = "QUATERNION"
        pb.rotation_quaternion = (1, 0, 0, 0)
    for m in skin.armature_modifiers(ob):
        m.use_deform_preserve_volume = dqs
    bpy.context.view_layer.objects.active = ob
    return ob, arm


def _pose(arm, bone, q):
    arm.pose.bones[bone].rotation_quaternion = q
    bpy.context.view_layer.update()


def _sculpt(ob, example, seed, amount=0.01):
    """Push a smooth bump into the example's posed copy; return the wanted positions (object space)."""
    st = ob.shapespace_psd
    copy = st.examples[example].sculpt
    co = meshes.vertex_positions(copy.data).astype(np.float64)
    rng = np.random.default_rng(seed)
    centre = co[rng.integers(len(co))]
    size = bounding_box_diagonal(co)
    fall = np.exp(-np.sum((co - centre) ** 2, axis=1) / (0.1 * size) ** 2)
    co = co + amount * size * fall[:, None] * rng.normal(size=3)
    copy.data.vertices.foreach_set("co", co.astype(np.float32).ravel())
    copy.data.update()
    return meshes.to_local(ob, meshes.to_world(copy, co))


@pytest.mark.parametrize("dqs", [False, True], ids=["lbs", "dqs"])
def test_apply_round_trip_matches_the_sculpt(registered, dqs):
    ob, arm = _cesium(dqs)
    bone = arm.pose.bones[5].name
    _pose(arm, bone, (0.9, 0.3, 0.2, 0.1))
    assert bpy.ops.shapespace.psd_add_example() == {"FINISHED"}
    st = ob.shapespace_psd
    assert [r.source for r in st.readers] == [bone]       # default pose space: the posed bone
    wanted = _sculpt(ob, st.examples[0].name, 1)
    assert bpy.ops.shapespace.psd_apply_example() == {"FINISHED"}
    assert bpy.ops.shapespace.psd_update() == {"FINISHED"}
    got = evaluated(ob)
    assert np.abs(got - wanted).max() / bounding_box_diagonal(wanted) < TOL


@pytest.mark.parametrize("method", ["PSD", "SBE", "WPSD"])
def test_each_example_is_reproduced_at_its_pose_and_blends_between(registered, method):
    ob, arm = _cesium()
    st = ob.shapespace_psd
    st.method = method
    b1, b2 = arm.pose.bones[5].name, arm.pose.bones[9].name
    poses = [((0.9, 0.3, 0.2, 0.1), (1, 0, 0, 0)), ((1, 0, 0, 0), (0.8, -0.4, 0.3, 0.2)),
             ((0.85, 0.2, -0.4, 0.1), (0.9, 0.1, 0.3, -0.2))]
    wanted = []
    for i, (q1, q2) in enumerate(poses):
        _pose(arm, b1, q1)
        _pose(arm, b2, q2)
        if i == 0:
            st.readers.add().source = b1
            st.readers.add().source = b2
        bpy.ops.shapespace.psd_add_example()
        wanted.append(_sculpt(ob, st.examples[i].name, 10 + i))
        st.active_example = i
        bpy.ops.shapespace.psd_apply_example()
    for i, (q1, q2) in enumerate(poses):
        _pose(arm, b1, q1)
        _pose(arm, b2, q2)
        assert bpy.ops.shapespace.psd_update() == {"FINISHED"}
        err = np.abs(evaluated(ob) - wanted[i]).max() / bounding_box_diagonal(wanted[i])
        assert err < TOL, (method, i, err)


def test_live_preview_follows_the_pose_and_bake_plays_without_the_add_on(registered, tmp_path):
    ob, arm = _cesium()
    st = ob.shapespace_psd
    bone = arm.pose.bones[5].name
    for i, q in enumerate([(0.9, 0.3, 0.2, 0.1), (0.9, -0.3, 0.1, 0.2)]):
        _pose(arm, bone, q)
        bpy.ops.shapespace.psd_add_example()
        _sculpt(ob, st.examples[i].name, 20 + i)
        st.active_example = i
        bpy.ops.shapespace.psd_apply_example()
    # animate the bone through both examples
    pb = arm.pose.bones[bone]
    scene = bpy.context.scene
    for f, q in ((1, (1, 0, 0, 0)), (10, (0.9, 0.3, 0.2, 0.1)), (20, (0.9, -0.3, 0.1, 0.2))):
        pb.rotation_quaternion = q
        pb.keyframe_insert("rotation_quaternion", frame=f)
    st.live_preview = True
    preview = {}
    for f in (4, 10, 15):
        scene.frame_set(f)       # the frame handler updates the correctives
        preview[f] = evaluated(ob)
    keys = ob.data.shape_keys.key_blocks
    scene.frame_set(15)
    between = ob.shapespace_face.confidence                 # live pose-space confidence (GP variance)
    scene.frame_set(10)
    assert keys[st.examples[0].name].value == pytest.approx(1.0, abs=1e-6)
    assert ob.shapespace_face.confidence == pytest.approx(0.0, abs=1e-6) and 1e-4 < between < 1.0
    st.live_preview = False
    assert bpy.ops.shapespace.psd_bake(frame_start=1, frame_end=20) == {"FINISHED"}
    path = str(tmp_path / "baked.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    SS.unregister()
    try:
        bpy.ops.wm.open_mainfile(filepath=path)
        ob2 = bpy.data.objects["Cesium_Man"]
        for f, want in preview.items():
            bpy.context.scene.frame_set(f)
            got = evaluated(ob2)
            assert np.abs(got - want).max() / bounding_box_diagonal(want) < TOL, f
    finally:
        SS.register()


def test_bad_examples_are_flagged_and_survive(registered, tmp_path):
    ob, arm = _cesium()
    st = ob.shapespace_psd
    bone = arm.pose.bones[5].name
    _pose(arm, bone, (0.9, 0.3, 0.2, 0.1))
    bpy.ops.shapespace.psd_add_example()
    _sculpt(ob, st.examples[0].name, 1)
    bpy.ops.shapespace.psd_apply_example()
    bpy.ops.shapespace.psd_add_example()          # the same pose saved twice, a different sculpt
    _sculpt(ob, st.examples[1].name, 2)
    st.active_example = 1
    bpy.ops.shapespace.psd_apply_example()
    assert "conflicting examples" in st.examples[0].flags and "conflicting examples" in st.examples[1].flags
    assert bpy.ops.shapespace.psd_update() == {"FINISHED"}          # regularised, not singular
    assert np.isfinite(evaluated(ob)).all()
    # save, reload, unregister / re-register with examples present
    path = str(tmp_path / "examples.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    SS.unregister()
    SS.register()
    bpy.ops.wm.open_mainfile(filepath=path)
    ob = bpy.data.objects["Cesium_Man"]
    assert [e.name for e in ob.shapespace_psd.examples] == [e for e in ("PSD_01", "PSD_02")]
    bpy.context.view_layer.objects.active = ob
    assert bpy.ops.shapespace.psd_update() == {"FINISHED"}


def test_renamed_bone_and_changed_topology_cancel_with_a_message(registered):
    ob, arm = _cesium()
    st = ob.shapespace_psd
    bone = arm.pose.bones[5].name
    _pose(arm, bone, (0.9, 0.3, 0.2, 0.1))
    bpy.ops.shapespace.psd_add_example()
    _sculpt(ob, st.examples[0].name, 3)
    bpy.ops.shapespace.psd_apply_example()
    arm.data.bones[bone].name = "Renamed"
    before = blend_fingerprint()
    with pytest.raises(RuntimeError, match="no longer exists"):
        bpy.ops.shapespace.psd_update()
    assert blend_fingerprint() == before
    arm.data.bones["Renamed"].name = bone
    st.examples[0].sculpt.data.vertices.add(2)
    with pytest.raises(RuntimeError, match="topology changed"):
        bpy.ops.shapespace.psd_apply_example()


def test_example_at_rest_pose_needs_readers(registered):
    ob, arm = _cesium()
    before = blend_fingerprint()
    with pytest.raises(RuntimeError, match="pose the rig away from its rest pose"):
        bpy.ops.shapespace.psd_add_example()
    assert blend_fingerprint() == before
    ob.shapespace_psd.readers.add().source = arm.pose.bones[2].name
    assert bpy.ops.shapespace.psd_add_example() == {"FINISHED"}     # explicit readers: rest pose is fine
    assert json.loads(ob.shapespace_psd.examples[0].pose)["values"] == pytest.approx([0.0] * 9)


@pytest.mark.parametrize("method", ["WPSD", "SBE"])
def test_point_cache_bake_plays_without_the_add_on(registered, tmp_path, method):
    ob, arm = _cesium()
    st = ob.shapespace_psd
    st.method = method
    bone = arm.pose.bones[5].name
    for i, q in enumerate([(0.9, 0.3, 0.2, 0.1), (0.9, -0.3, 0.1, 0.2), (0.8, 0.1, -0.5, 0.3)]):
        _pose(arm, bone, q)
        bpy.ops.shapespace.psd_add_example()
        _sculpt(ob, st.examples[i].name, 30 + i)
        st.active_example = i
        bpy.ops.shapespace.psd_apply_example()
    pb = arm.pose.bones[bone]
    for f, q in ((1, (1, 0, 0, 0)), (8, (0.9, 0.3, 0.2, 0.1)), (16, (0.9, -0.3, 0.1, 0.2))):
        pb.rotation_quaternion = q
        pb.keyframe_insert("rotation_quaternion", frame=f)
    scene = bpy.context.scene
    preview = {}
    for f in (3, 8, 12):
        scene.frame_set(f)
        bpy.ops.shapespace.psd_update()
        preview[f] = evaluated(ob)
    pc2 = str(tmp_path / "correctives.pc2")
    assert bpy.ops.shapespace.psd_bake_cache(filepath=pc2, frame_start=1, frame_end=16) == {"FINISHED"}
    assert ob.modifiers[0].type == "MESH_CACHE"
    path = str(tmp_path / "cached.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    SS.unregister()
    try:
        bpy.ops.wm.open_mainfile(filepath=path)
        ob2 = bpy.data.objects["Cesium_Man"]
        for f, want in preview.items():
            bpy.context.scene.frame_set(f)
            assert np.abs(evaluated(ob2) - want).max() / bounding_box_diagonal(want) < TOL, f
    finally:
        SS.register()


def test_pc2_round_trip(tmp_path):
    from shapespace.core.pointcache import read_pc2, write_pc2
    from shapespace.core.result import ShapeSpaceError
    data = np.random.default_rng(0).normal(size=(5, 40, 3))
    write_pc2(str(tmp_path / "a.pc2"), data, start_frame=3.0)
    back, start, rate = read_pc2(str(tmp_path / "a.pc2"))
    assert start == 3.0 and rate == 1.0
    np.testing.assert_allclose(back, data, atol=1e-6)
    (tmp_path / "bad.pc2").write_bytes(b"nope")
    with pytest.raises(ShapeSpaceError, match="too short"):
        read_pc2(str(tmp_path / "bad.pc2"))


def test_undo_and_redo_across_add_and_apply(registered):
    ob, arm = _cesium()
    _pose(arm, arm.pose.bones[5].name, (0.9, 0.3, 0.2, 0.1))
    bpy.ops.ed.undo_push(message="start")
    bpy.ops.shapespace.psd_add_example()
    bpy.ops.ed.undo_push(message="add")
    _sculpt(ob, "PSD_01", 4)
    bpy.ops.shapespace.psd_apply_example()
    bpy.ops.ed.undo_push(message="apply")
    key_after = meshes.vertex_positions(bpy.data.objects["Cesium_Man"].data)  # basis untouched
    bpy.ops.ed.undo()
    bpy.ops.ed.undo()
    ob = bpy.data.objects["Cesium_Man"]
    assert len(ob.shapespace_psd.examples) == 0
    assert ob.data.shape_keys is None or "PSD_01" not in ob.data.shape_keys.key_blocks
    bpy.ops.ed.redo()
    bpy.ops.ed.redo()
    ob = bpy.data.objects["Cesium_Man"]
    assert [e.name for e in ob.shapespace_psd.examples] == ["PSD_01"]
    np.testing.assert_allclose(meshes.vertex_positions(ob.data), key_after)
    bpy.context.view_layer.objects.active = ob
    assert bpy.ops.shapespace.psd_update() == {"FINISHED"}


def test_mirror_and_move_example(registered):
    import_file(shared("rpm_brunette", "brunette-t.glb"))
    ob = bpy.data.objects["Wolf3D_Body"]
    arm = skin.armature_modifiers(ob)[0].object
    bpy.context.view_layer.objects.active = ob
    for pb in arm.pose.bones:
        pb.rotation_mode = "QUATERNION"
        pb.rotation_quaternion = (1, 0, 0, 0)
    st = ob.shapespace_psd
    st.readers.add().source = "LeftArm"
    st.readers.add().source = "RightArm"
    _pose(arm, "LeftArm", (0.9, 0.2, 0.3, 0.25))
    bpy.ops.shapespace.psd_add_example()
    _sculpt(ob, "PSD_01", 7)
    bpy.ops.shapespace.psd_apply_example()
    with pytest.raises(RuntimeError, match="not symmetric"):   # the avatar is only nearly symmetric
        bpy.ops.shapespace.psd_mirror_example()
    assert bpy.ops.shapespace.psd_mirror_example(tolerance=0.01) == {"FINISHED"} and len(st.examples) == 2
    # the mirrored example sits where the flipped pose reads
    _pose(arm, "LeftArm", (1, 0, 0, 0))
    _pose(arm, "RightArm", (0.9, 0.2, -0.3, -0.25))
    got = np.array(json.loads(st.examples[1].pose)["values"])
    np.testing.assert_allclose(got, posespace.read_pose(ob), atol=1e-6)
    # moving example 1 to another pose makes its sculpt appear there instead (pseudo-example)
    _pose(arm, "RightArm", (0.95, -0.1, 0.2, 0.2))
    st.active_example = 1
    st.method = "SBE"
    assert bpy.ops.shapespace.psd_move_example() == {"FINISHED"}
    assert bpy.ops.shapespace.psd_update() == {"FINISHED"}
    assert ob.data.shape_keys.key_blocks[st.examples[1].name].value == pytest.approx(1.0, abs=1e-6)


def test_bbones_are_inverted_through_blenders_own_evaluation(registered):
    ob, arm = _cesium()
    bone = arm.pose.bones[5].name
    bpy.context.view_layer.objects.active = arm
    bpy.ops.object.mode_set(mode="EDIT")
    for eb in arm.data.edit_bones:
        if eb.name in (bone, arm.pose.bones[4].name, arm.pose.bones[6].name):
            eb.bbone_segments = 6
    bpy.ops.object.mode_set(mode="OBJECT")
    arm.pose.bones[bone].bbone_curveinx = 0.05
    arm.pose.bones[bone].bbone_easein = 0.8
    bpy.context.view_layer.objects.active = ob
    assert not posespace.modelled_exactly(ob)
    _pose(arm, bone, (0.9, 0.3, 0.2, 0.1))
    bpy.ops.shapespace.psd_add_example()
    wanted = _sculpt(ob, "PSD_01", 9)
    assert bpy.ops.shapespace.psd_apply_example() == {"FINISHED"}
    assert "ShapeSpace_invert" not in ob.data.shape_keys.key_blocks
    bpy.ops.shapespace.psd_update()
    assert np.abs(evaluated(ob) - wanted).max() / bounding_box_diagonal(wanted) < TOL


def test_driven_targets_follow_pose_space_and_bake(registered, tmp_path):
    """7.3.3: a bone channel and a custom property driven from pose-space examples."""
    ob, arm = _cesium()
    st = ob.shapespace_psd
    bone = arm.pose.bones[5].name
    other = arm.pose.bones[6].name
    arm["exertion"] = 0.0
    st.readers.add().source = bone
    assert bpy.ops.shapespace.psd_add_target(data_path=f'pose.bones["{other}"].scale', index=0) == {"FINISHED"}
    assert bpy.ops.shapespace.psd_add_target(data_path='["exertion"]') == {"FINISHED"}
    with pytest.raises(RuntimeError, match="no property"):
        bpy.ops.shapespace.psd_add_target(data_path="not.a.path")
    values = [(1.0, 0.0), (1.4, 0.8)]
    poses = [(1, 0, 0, 0), (0.8, 0.6, 0.0, 0.0)]
    for q, (sx, ex) in zip(poses, values):
        _pose(arm, bone, q)
        bpy.ops.shapespace.psd_add_example(sculpt_copy=False)
        arm.pose.bones[other].scale[0] = sx
        arm["exertion"] = ex
        assert bpy.ops.shapespace.psd_record_targets() == {"FINISHED"}
    for q, (sx, ex) in zip(poses, values):
        arm.pose.bones[other].scale[0] = 0.5
        _pose(arm, bone, q)
        bpy.ops.shapespace.psd_update()
        assert arm.pose.bones[other].scale[0] == pytest.approx(sx, abs=1e-6)
        assert arm["exertion"] == pytest.approx(ex, abs=1e-6)   # stored in single precision
    _pose(arm, bone, (0.95, 0.31, 0.0, 0.0))                   # between the examples
    bpy.ops.shapespace.psd_update()
    assert 1.0 < arm.pose.bones[other].scale[0] < 1.4 and 0.0 < arm["exertion"] < 0.8
    # bake: the targets are keyed and play without the add-on
    pb = arm.pose.bones[bone]
    for f, q in ((1, poses[0]), (10, poses[1])):
        pb.rotation_quaternion = q
        pb.keyframe_insert("rotation_quaternion", frame=f)
    bpy.context.scene.frame_set(5)
    bpy.ops.shapespace.psd_update()
    want = arm.pose.bones[other].scale[0]
    assert bpy.ops.shapespace.psd_bake(frame_start=1, frame_end=10) == {"FINISHED"}
    path = str(tmp_path / "targets.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    SS.unregister()
    try:
        bpy.ops.wm.open_mainfile(filepath=path)
        bpy.context.scene.frame_set(5)
        assert bpy.data.objects["Armature"].pose.bones[other].scale[0] == pytest.approx(want, abs=1e-5)
    finally:
        SS.register()


def test_property_shape_key_swing_and_twist_readers(registered):
    """Adjective (custom property), weighted-pose-space (shape key), swing and twist readers read Blender."""
    from shapespace.core.posespace.readers import PoseReader, pose_features, swing_twist
    ob, arm = _cesium()
    st = ob.shapespace_psd
    bone = arm.pose.bones[5].name
    arm["exertion"] = 0.25
    ob.shape_key_add(name="Basis")
    ob.shape_key_add(name="smile").value = 0.6
    for kind, source in (("PROPERTY", '["exertion"]'), ("SHAPE_KEY", "smile"), ("SWING", bone), ("TWIST", bone)):
        r = st.readers.add()
        r.kind, r.source = kind, source
    q = np.array([0.8, 0.2, 0.5, 0.26])
    q /= np.linalg.norm(q)
    _pose(arm, bone, tuple(q))
    got = posespace.read_pose(ob)
    want = pose_features([PoseReader("property", "x"), PoseReader("shape_key", "smile"),
                          PoseReader("swing", bone), PoseReader("twist", bone)], [0.25, 0.6, q, q])
    np.testing.assert_allclose(got, want, atol=1e-6)
    # a pure roll (twist about the bone's Y axis) leaves the swing reader still
    twist_only = np.array([np.cos(0.4), 0.0, np.sin(0.4), 0.0])
    _pose(arm, bone, tuple(twist_only))
    swing_part = posespace.read_pose(ob)[2:5]
    np.testing.assert_allclose(swing_part, 0.0, atol=1e-6)
    assert abs(swing_twist(twist_only)[1] - 0.8) < 1e-9


def test_example_blobs_are_versioned_and_0_1_0_bare_lists_still_load(registered):
    """Example poses / target values are stored as versioned JSON; 0.1.0 wrote bare lists."""
    ob, arm = _cesium()
    st = ob.shapespace_psd
    bone = arm.pose.bones[5].name
    _pose(arm, bone, (0.9, 0.3, 0.2, 0.1))
    assert bpy.ops.shapespace.psd_add_example(sculpt_copy=False) == {"FINISHED"}
    ex = st.examples[0]
    stored = json.loads(ex.pose)
    assert stored["schema_version"] == 1 and len(stored["values"]) == 9
    assert json.loads(ex.target_values) == {"schema_version": 1, "values": []}
    want = posespace.read_pose(ob)
    ex.pose = json.dumps(stored["values"])            # as ShapeSpace 0.1.0 saved it
    ex.target_values = "[]"
    assert bpy.ops.shapespace.psd_update() == {"FINISHED"}
    np.testing.assert_allclose(posespace.example_pose(ex), want, atol=1e-6)
    ex.pose = '{"values": [0.1, "x"]'                  # damaged: the error names the example
    with pytest.raises(RuntimeError, match="damaged ShapeSpace data.*PSD_01"):
        bpy.ops.shapespace.psd_update()
    ex.pose = json.dumps({"schema_version": 1, "values": [0.1, "x"]})
    with pytest.raises(RuntimeError, match="PSD_01.*numbers"):
        bpy.ops.shapespace.psd_update()


# ------------------------------------------------------------------ bad scenes (issue #10)
PSD_OPS = sorted(name for name in OPERATOR_CALLS if name.startswith("psd_"))
BAD_OUTCOMES = ("traceback", "refused_without_message", "silent_change", "nan_written", "linked_changed")


# ------------------------------------------------------------------ scenes
def _activate(ob):
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    bpy.context.view_layer.objects.active = ob
    ob.select_set(True)


def _simple(example=True, target=True):
    """RiggedSimple with its last bone posed, a driven target and (by default) one recorded example PSD_01."""
    posespace_preview.CACHE.clear()
    import_file(shared("rigged_simple", "RiggedSimple.glb"))
    ob = bpy.data.objects["Cylinder"]
    arm = next(o for o in bpy.data.objects if o.type == "ARMATURE")
    if arm.animation_data:
        arm.animation_data.action = None
    pb = arm.pose.bones[-1]
    pb.rotation_mode = "QUATERNION"
    pb.rotation_quaternion = (0.9, 0.3, 0.2, 0.1)
    arm["x"] = 0.5
    _activate(ob)
    bpy.context.view_layer.update()
    if target:
        assert bpy.ops.shapespace.psd_add_target(data_path='["x"]') == {"FINISHED"}
    if example:
        assert bpy.ops.shapespace.psd_add_example() == {"FINISHED"}
    return ob, arm


def _kwargs(op, tmp_path):
    kw = dict(OPERATOR_CALLS[op])
    if op == "psd_bake_cache":
        kw["filepath"] = str(tmp_path / "c.pc2")
    return kw


def _one_line_naming(message, *culprits):
    lines = [line for line in message.strip().splitlines() if line.strip()]
    assert len(lines) == 1, message
    assert any(c in message for c in culprits), (culprits, message)


def _panel_lines(ob):
    _activate(ob)
    log = []
    call = type("PanelCall", (), {"layout": Layout(log), "bl_idname": "SHAPESPACE_PT_correctives"})()
    bpy.types.SHAPESPACE_PT_correctives.draw(call, bpy.context)
    return [text for kind, text in log if kind == "label"]


def _scrub(frames=(2, 3, 4, 5)):
    for f in frames:
        bpy.context.scene.frame_set(f)


# ------------------------------------------------------------------ r17: every shape key deleted
@pytest.mark.parametrize("op", PSD_OPS)
def test_deleting_every_shape_key_leaves_each_operator_refusing_in_one_line(registered, tmp_path, op):
    ob, arm = _simple()
    ob.shape_key_clear()                    # Object Data ▸ Shape Keys ▸ Delete All Shape Keys
    outcome, message = classify_operator_call(op, _kwargs(op, tmp_path))
    if op in ("psd_remove_example", "psd_add_target"):     # the way out, and unrelated to the examples
        assert outcome == "finished", message
        return
    assert outcome in ("refused", "cancelled"), (outcome, message)
    _one_line_naming(message, "PSD_01")


def test_remove_example_cleans_up_after_the_keys_were_deleted(registered):
    ob, arm = _simple()
    ob.shape_key_clear()
    assert bpy.ops.shapespace.psd_remove_example() == {"FINISHED"}
    assert len(ob.shapespace_psd.examples) == 0 and "PSD_01_sculpt" not in bpy.data.objects
    assert bpy.ops.shapespace.psd_add_example() == {"FINISHED"}


# ------------------------------------------------------------------ the live preview handler
def _delete_keys(ob, arm):
    ob.shape_key_clear()


def _damage_pose(ob, arm):
    ob.shapespace_psd.examples[0].pose = "{not json"


def _missing_bone(ob, arm):
    ob.shapespace_psd.readers[0].source = "NoSuchBone"


def _nan_bone(ob, arm):
    arm.pose.bones[-1].rotation_quaternion = (float("nan"), 0.0, 0.0, 0.0)


def _unexpected(ob, arm, monkeypatch):
    def broken(*args, **kwargs):
        raise AttributeError("'NoneType' object has no attribute 'key_blocks'")
    monkeypatch.setattr(posespace, "preview", broken)


@pytest.mark.parametrize("damage,culprit", [(_delete_keys, "PSD_01"), (_damage_pose, "PSD_01"),
                                            (_missing_bone, "NoSuchBone"), (_nan_bone, "Root.003"),
                                            (_unexpected, "AttributeError")],
                         ids=["keys_deleted", "damaged_pose", "missing_bone", "nan_bone", "unexpected_error"])
def test_live_preview_stops_once_with_a_message_and_never_a_traceback(registered, capfd, monkeypatch, damage,
                                                                        culprit):
    ob, arm = _simple()
    st = ob.shapespace_psd
    st.live_preview = True
    _scrub((2,))
    capfd.readouterr()
    if damage is _unexpected:
        damage(ob, arm, monkeypatch)
    else:
        damage(ob, arm)
    posespace_preview.CACHE.clear()         # as after saving and reopening the damaged file
    _scrub()
    out, err = capfd.readouterr()
    assert "Traceback" not in out + err and "Error in bpy.app.handlers" not in out + err, out + err
    assert (out + err).count("Live Preview of 'Cylinder' stopped") == 1, out + err
    assert not st.live_preview and culprit in st.preview_message
    assert any("Live Preview stopped" in line and culprit in line for line in _panel_lines(ob))


def test_live_preview_resumes_after_the_fix_and_forgets_the_message(registered, capfd):
    ob, arm = _simple()
    st = ob.shapespace_psd
    st.readers[0].source = "NoSuchBone"
    st.live_preview = True
    _scrub()
    assert not st.live_preview and "NoSuchBone" in st.preview_message
    st.readers[0].source = arm.pose.bones[-1].name
    st.live_preview = True
    _scrub((7, 8))
    assert st.live_preview and st.preview_message == ""
    assert "Traceback" not in "".join(capfd.readouterr())


# ------------------------------------------------------------------ switching methods (CesiumMan)
METHODS = ("PSD", "SBE", "WPSD")
PAIRS = [(a, b) for a in METHODS for b in METHODS if a != b]


def _cesium_scene(path):
    """CesiumMan with three applied examples on one bone, posed between them, saved to ``path``."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    import_file(shared("cesium_man", "CesiumMan.glb"))
    ob, arm = bpy.data.objects["Cesium_Man"], bpy.data.objects["Armature"]
    arm.animation_data.action = None
    for pb in arm.pose.bones:
        pb.rotation_mode = "QUATERNION"
        pb.rotation_quaternion = (1, 0, 0, 0)
    _activate(ob)
    st = ob.shapespace_psd
    bone = arm.pose.bones[5]
    rng = np.random.default_rng(5)
    for i, q in enumerate([(0.9, 0.3, 0.2, 0.1), (0.9, -0.3, 0.1, 0.2), (0.8, 0.1, -0.5, 0.3)]):
        bone.rotation_quaternion = q
        bpy.context.view_layer.update()
        assert bpy.ops.shapespace.psd_add_example() == {"FINISHED"}
        copy = st.examples[i].sculpt
        co = meshes.vertex_positions(copy.data).astype(np.float64)
        centre = co[rng.integers(len(co))]
        fall = np.exp(-np.sum((co - centre) ** 2, axis=1) / (0.1 * bounding_box_diagonal(co)) ** 2)
        co += 0.02 * bounding_box_diagonal(co) * fall[:, None] * rng.normal(size=3)
        copy.data.vertices.foreach_set("co", co.astype(np.float32).ravel())
        copy.data.update()
        st.active_example = i
        assert bpy.ops.shapespace.psd_apply_example() == {"FINISHED"}
    bone.rotation_quaternion = (0.95, 0.1, 0.2, 0.1)
    for f in (1, 3):                         # a still pose, keyed so a bake has frames to sample
        bone.keyframe_insert("rotation_quaternion", frame=f)
    bpy.ops.wm.save_as_mainfile(filepath=path)


def _open(path, method=None):
    bpy.ops.wm.open_mainfile(filepath=path)
    ob = bpy.data.objects["Cesium_Man"]
    _activate(ob)
    if method:
        ob.shapespace_psd.method = method
    bpy.context.scene.frame_set(2)
    return ob


@pytest.fixture(scope="module")
def switching(registered, tmp_path_factory):
    """The saved scene and each method's result evaluated fresh (its own file, one Update) by Blender."""
    path = str(tmp_path_factory.mktemp("switch") / "switch.blend")
    _cesium_scene(path)
    fresh = {}
    for m in METHODS:
        ob = _open(path, m)
        assert bpy.ops.shapespace.psd_update() == {"FINISHED"}
        fresh[m] = evaluated(ob)
    assert all(np.abs(fresh[a] - fresh[b]).max() > 1e-4 for a, b in PAIRS)   # the methods do differ here
    return path, fresh


def _close(got, want):
    return float(np.abs(got - want).max() / bounding_box_diagonal(want))


@pytest.mark.parametrize("first,then", PAIRS, ids=[f"{a}_to_{b}" for a, b in PAIRS])
def test_switching_methods_gives_the_methods_own_result(registered, switching, first, then):
    path, fresh = switching
    ob = _open(path, first)
    assert bpy.ops.shapespace.psd_update() == {"FINISHED"}
    ob.shapespace_psd.method = then
    assert bpy.ops.shapespace.psd_update() == {"FINISHED"}
    assert _close(evaluated(ob), fresh[then]) < TOL
    # the same through Live Preview while scrubbing
    ob = _open(path, first)
    st = ob.shapespace_psd
    st.live_preview = True
    bpy.context.scene.frame_set(1)
    st.method = then
    bpy.context.scene.frame_set(2)
    assert _close(evaluated(ob), fresh[then]) < TOL
    st.live_preview = False
    if then == "WPSD":
        return
    # Bake Correctives right after the switch bakes only the active method's correctives
    ob = _open(path, first)
    assert bpy.ops.shapespace.psd_update() == {"FINISHED"}
    ob.shapespace_psd.method = then
    assert bpy.ops.shapespace.psd_bake(frame_start=1, frame_end=3) == {"FINISHED"}
    keys = ob.data.shape_keys.key_blocks
    for f in (1, 2, 3):
        bpy.context.scene.frame_set(f)
        assert _close(evaluated(ob), fresh[then]) < TOL, f
        assert posespace.WPSD_KEY not in keys or keys[posespace.WPSD_KEY].value == 0.0


def test_a_muted_example_leaves_the_correctives(registered, switching):
    path, fresh = switching
    ob = _open(path, "SBE")
    st = ob.shapespace_psd
    assert bpy.ops.shapespace.psd_update() == {"FINISHED"}
    keys = ob.data.shape_keys.key_blocks
    assert abs(keys[st.examples[1].name].value) > 1e-3
    st.examples[1].mute = True
    assert bpy.ops.shapespace.psd_update() == {"FINISHED"}
    assert keys[st.examples[1].name].value == 0.0
    with_mute = evaluated(ob)
    ob = _open(path, "SBE")
    ob.shapespace_psd.examples[1].mute = True
    assert bpy.ops.shapespace.psd_update() == {"FINISHED"}
    assert _close(evaluated(ob), with_mute) < TOL
    # a bake made before muting is re-baked without the muted example
    ob = _open(path, "SBE")
    st = ob.shapespace_psd
    assert bpy.ops.shapespace.psd_bake(frame_start=1, frame_end=3) == {"FINISHED"}
    st.examples[1].mute = True
    assert bpy.ops.shapespace.psd_bake(frame_start=1, frame_end=3) == {"FINISHED"}
    for f in (1, 3):
        bpy.context.scene.frame_set(f)
        assert ob.data.shape_keys.key_blocks[st.examples[1].name].value == 0.0
        assert _close(evaluated(ob), with_mute) < TOL


# ------------------------------------------------------------------ r31: the point-cache path
HOSTILE_NAMES = ["../../../escape", "/tmp/shapespace_abs_escape", "..", "a/b\\c", "C:\\x"]


def _saved_shot(tmp_path, name=None):
    ob, arm = _simple(target=False)
    if name is not None:
        ob.name = name
    folder = tmp_path / "project" / "shots" / "sh010"
    folder.mkdir(parents=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(folder / "shot.blend"))
    _activate(ob)
    return ob, folder


def _all_files(root):
    return sorted(os.path.join(d, f) for d, _, files in os.walk(root) for f in files)


@pytest.mark.parametrize("name", HOSTILE_NAMES, ids=range(len(HOSTILE_NAMES)))
def test_the_default_cache_path_stays_in_the_blend_folder(registered, tmp_path, name):
    abs_target = "/tmp/shapespace_abs_escape_correctives.pc2"
    if os.path.exists(abs_target):
        os.remove(abs_target)
    ob, folder = _saved_shot(tmp_path, name)
    before = set(_all_files(tmp_path))
    assert bpy.ops.shapespace.psd_bake_cache(frame_start=1, frame_end=2) == {"FINISHED"}
    new = set(_all_files(tmp_path)) - before
    assert len(new) == 1, new
    written = new.pop()
    assert os.path.dirname(written) == str(folder) and written.endswith("_correctives.pc2")
    assert ".." not in os.path.basename(written) and "\\" not in os.path.basename(written)
    assert not os.path.exists(abs_target)
    stored = ob.modifiers[posespace.MESH_CACHE_NAME].filepath      # `//`-relative by the preference (#12)
    assert os.path.normpath(bpy.path.abspath(stored)) == written
    assert read_pc2(written)[0].shape == (2, len(ob.data.vertices), 3)


def test_an_existing_file_at_the_default_path_is_never_overwritten_unasked(registered, tmp_path):
    ob, folder = _saved_shot(tmp_path)
    path = folder / posespace.default_cache_name(ob)
    path.write_bytes(b"someone else's file")
    before = blend_fingerprint()
    with pytest.raises(RuntimeError, match="already exists"):
        bpy.ops.shapespace.psd_bake_cache(frame_start=1, frame_end=2)
    assert path.read_bytes() == b"someone else's file" and blend_fingerprint() == before
    assert posespace.MESH_CACHE_NAME not in ob.modifiers
    assert bpy.ops.shapespace.psd_bake_cache(frame_start=1, frame_end=2, overwrite=True) == {"FINISHED"}
    assert read_pc2(str(path))[0].shape[0] == 2
    # re-baking the mesh's own cache needs no Overwrite
    assert bpy.ops.shapespace.psd_bake_cache(frame_start=1, frame_end=3) == {"FINISHED"}
    assert read_pc2(str(path))[0].shape[0] == 3


def test_a_chosen_path_never_replaces_the_blend_or_a_file_of_another_kind(registered, tmp_path):
    ob, folder = _saved_shot(tmp_path)
    blend = folder / "shot.blend"
    saved = blend.read_bytes()
    for bad, match in ((blend, "is a .blend file"), (folder, "is a folder"),
                       (folder / "missing" / "c.pc2", "does not exist")):
        with pytest.raises(RuntimeError, match=match):
            bpy.ops.shapespace.psd_bake_cache(filepath=str(bad), frame_start=1, frame_end=2)
    other = folder / "notes.txt"
    other.write_text("keep me")
    with pytest.raises(RuntimeError, match="not a point cache"):
        bpy.ops.shapespace.psd_bake_cache(filepath=str(other), frame_start=1, frame_end=2)
    assert other.read_text() == "keep me" and blend.read_bytes() == saved
    chosen = folder / "chosen.pc2"
    assert bpy.ops.shapespace.psd_bake_cache(filepath=str(chosen), frame_start=1, frame_end=2) == {"FINISHED"}
    assert bpy.ops.shapespace.psd_bake_cache(filepath=str(chosen), frame_start=1, frame_end=4) == {"FINISHED"}
    assert read_pc2(str(chosen))[0].shape[0] == 4
    assert not [f for f in _all_files(folder) if f.endswith(".tmp")]


# ------------------------------------------------------------------ r18, r07: NaN basis, Edit Mode
def test_mirror_example_on_a_nan_basis_names_the_key_and_vertex(registered):
    ob, arm = _simple()
    kb = ob.data.shape_keys.key_blocks[0]
    co = np.empty(len(kb.data) * 3, np.float32)
    kb.data.foreach_get("co", co)
    co[7] = np.nan                                     # vertex 2, y
    kb.data.foreach_set("co", co)
    outcome, message = classify_operator_call("psd_mirror_example", {})
    assert outcome == "cancelled", message
    _one_line_naming(message, f"shape key {kb.name!r}")
    assert "vertex 2" in message


def test_confidence_in_edit_mode_is_refused_by_its_poll(registered):
    ob, arm = _simple()
    bpy.ops.object.mode_set(mode="EDIT")
    outcome, message = classify_operator_call("psd_confidence", {})
    assert outcome == "refused" and "Edit Mode" in message, message


def test_apply_sculpt_refuses_a_mesh_or_sculpt_copy_in_edit_mode(registered):
    ob, arm = _simple()
    copy = ob.shapespace_psd.examples[0].sculpt
    co = meshes.vertex_positions(copy.data)
    copy.data.vertices.foreach_set("co", (co + 0.01).astype(np.float32).ravel())
    bpy.ops.object.mode_set(mode="EDIT")
    outcome, message = classify_operator_call("psd_apply_example", {})
    assert outcome == "refused" and "'Cylinder' is in Edit Mode" in message, message
    with pytest.raises(ShapeSpaceError, match="'Cylinder' is in Edit Mode"):
        posespace.apply_example(ob, "PSD_01", sculpt_positions=co)
    bpy.ops.object.mode_set(mode="OBJECT")
    _activate(copy)
    bpy.ops.object.mode_set(mode="EDIT")                  # the sculpt copy alone in Edit Mode
    _activate(ob)
    assert ob.mode == "OBJECT" and copy.mode == "EDIT"
    outcome, message = classify_operator_call("psd_apply_example", {})
    assert outcome == "refused" and "'PSD_01_sculpt' is in Edit Mode" in message, message
    before = blend_fingerprint()
    with pytest.raises(ShapeSpaceError, match="'PSD_01_sculpt' of 'PSD_01' is in Edit Mode"):
        posespace.apply_example(ob, "PSD_01")
    assert blend_fingerprint() == before


# ------------------------------------------------------------------ NaN inputs
def _nan_sculpt(ob, arm):
    copy = ob.shapespace_psd.examples[0].sculpt
    co = meshes.vertex_positions(copy.data)
    co[11, 0] = np.nan
    copy.data.vertices.foreach_set("co", co.astype(np.float32).ravel())


def _nan_scale(ob, arm):
    ob.shapespace_psd.readers[0].scale = float("nan")


def _nan_target(ob, arm):
    arm["x"] = float("nan")


NAN_CASES = {
    "sculpt": (_nan_sculpt, ["psd_apply_example"], "PSD_01_sculpt"),
    "bone": (_nan_bone, ["psd_update", "psd_add_example", "psd_move_example", "psd_confidence", "psd_bake"],
             "bone 'Root.003'"),
    "reader_scale": (_nan_scale, ["psd_update", "psd_add_example", "psd_mirror_example", "psd_bake_cache"],
                     "reader 1"),
    "target": (_nan_target, ["psd_add_example", "psd_record_targets"], "'[\"x\"]'"),
}


@pytest.mark.parametrize("case,op", [(c, op) for c, (_, ops, _) in NAN_CASES.items() for op in ops])
def test_nan_inputs_are_refused_naming_the_culprit_and_nothing_is_written(registered, tmp_path, case, op):
    damage, _, culprit = NAN_CASES[case]
    ob, arm = _simple()
    damage(ob, arm)
    bpy.context.view_layer.update()
    outcome, message = classify_operator_call(op, _kwargs(op, tmp_path))
    assert outcome == "cancelled", (outcome, message)
    _one_line_naming(message, culprit)
    assert not os.path.exists(tmp_path / "c.pc2")


def test_nan_sculpt_vertex_is_named(registered):
    ob, arm = _simple()
    _nan_sculpt(ob, arm)
    with pytest.raises(ShapeSpaceError, match="vertex 11"):
        posespace.apply_example(ob, "PSD_01")


# ------------------------------------------------------------------ r21: damaged stored data
def _pose_text(text):
    def damage(ob, arm):
        ob.shapespace_psd.examples[0].pose = text
    return damage


def _pseudo_text(text):
    def damage(ob, arm):
        ob.shapespace_psd.examples[0].pseudo_pose = text
    return damage


def _targets_text(text):
    def damage(ob, arm):
        ob.shapespace_psd.examples[0].target_values = text
    return damage


def _sculpt_deleted(ob, arm):
    bpy.data.objects.remove(ob.shapespace_psd.examples[0].sculpt)


def _key_deleted(ob, arm):
    ob.shape_key_remove(ob.data.shape_keys.key_blocks["PSD_01"])


#: damage → (culprit named in refusals, operators that may finish because they do not need the damaged part)
DAMAGES = {
    "pose_not_json": (_pose_text("{not json"), "PSD_01", ()),
    "pose_wrong_type": (_pose_text('{"schema_version": 1, "values": "abc"}'), "PSD_01", ()),
    "pose_missing_field": (_pose_text('{"schema_version": 1}'), "PSD_01", ()),
    "pose_not_an_object": (_pose_text("42"), "PSD_01", ()),
    "pose_nan": (_pose_text("[NaN, 1]"), "PSD_01", ()),
    "pseudo_pose_wrong_type": (_pseudo_text('{"schema_version": 1, "values": [1, "a"]}'), "PSD_01", ()),
    "target_values_not_json": (_targets_text("[1,"), "PSD_01", ()),
    "target_values_nested": (_targets_text('{"schema_version": 1, "values": [[1]]}'), "PSD_01", ()),
    "sculpt_deleted": (_sculpt_deleted, "PSD_01",
                       ("psd_update", "psd_bake", "psd_bake_cache", "psd_confidence", "psd_move_example",
                        "psd_mirror_example", "psd_record_targets", "psd_add_example")),
    "key_deleted": (_key_deleted, "PSD_01", ()),
    "missing_bone": (_missing_bone, "NoSuchBone", ("psd_apply_example", "psd_record_targets")),
}
ALWAYS_FINISH = ("psd_remove_example", "psd_add_target")


@pytest.mark.parametrize("damage", sorted(DAMAGES))
@pytest.mark.parametrize("op", PSD_OPS)
def test_damaged_stored_data_is_refused_in_one_line_naming_it(registered, tmp_path, damage, op):
    fn, culprit, may_finish = DAMAGES[damage]
    ob, arm = _simple()
    fn(ob, arm)
    outcome, message = classify_operator_call(op, _kwargs(op, tmp_path))
    assert outcome not in BAD_OUTCOMES, (outcome, message)
    if op in ALWAYS_FINISH or op in may_finish:
        assert outcome in ("finished", "refused", "cancelled"), (outcome, message)
        if outcome == "finished":
            return
    else:
        assert outcome in ("refused", "cancelled"), (outcome, message)
    _one_line_naming(message, culprit)


@pytest.mark.parametrize("damage", sorted(DAMAGES))
def test_damaged_stored_data_in_the_panel_and_the_preview(registered, capfd, damage):
    fn, culprit, _ = DAMAGES[damage]
    ob, arm = _simple()
    st = ob.shapespace_psd
    fn(ob, arm)
    lines = _panel_lines(ob)                        # the draw never raises, and says what is wrong
    if damage != "sculpt_deleted":
        assert any(culprit in line for line in lines), lines
    st.live_preview = True
    _scrub()
    out, err = capfd.readouterr()
    assert "Traceback" not in out + err and "Error in bpy.app.handlers" not in out + err, out + err
    if damage == "sculpt_deleted":                   # the sculpt copy is not needed to preview
        assert st.live_preview
    else:
        assert not st.live_preview and culprit in st.preview_message
        assert (out + err).count("Live Preview of 'Cylinder' stopped") == 1


# ------------------------------------------------------------------ progress
def test_long_operations_report_progress(registered, tmp_path):
    ob, arm = _simple()
    assert bpy.ops.shapespace.psd_apply_example() == {"FINISHED"}
    scene = bpy.context.scene
    for bake in (lambda p: posespace.bake_weights(ob, scene, 1, 6, progress=p),
                 lambda p: posespace.bake_point_cache(ob, scene, 1, 6, str(tmp_path / "p.pc2"), progress=p)):
        seen = []
        bake(seen.append)
        assert len(seen) == 6 and seen == sorted(seen) and seen[-1] == 1.0


def test_apply_through_blenders_evaluation_reports_progress(registered):
    ob, arm = _simple()
    mod = ob.modifiers.new("Twist", "SIMPLE_DEFORM")   # not modelled exactly: inverted through Blender
    mod.angle = 0.05
    assert not posespace.modelled_exactly(ob)
    seen = []
    posespace.apply_example(ob, "PSD_01", progress=seen.append)
    assert seen and all(0.0 <= s < 1.0 for s in seen) and seen == sorted(seen)
    assert posespace.TEMP_KEY not in ob.data.shape_keys.key_blocks


def test_stored_example_blobs_stay_readable_after_the_checks(registered):
    """The checks read, never rewrite: a 0.1.0 bare-list pose still loads and is left as it was."""
    ob, arm = _simple()
    ex = ob.shapespace_psd.examples[0]
    values = json.loads(ex.pose)["values"]
    ex.pose = json.dumps(values)
    assert posespace.problem(ob) == ""
    assert ex.pose == json.dumps(values)
    assert bpy.ops.shapespace.psd_update() == {"FINISHED"}
