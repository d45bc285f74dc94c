"""Pose-space correctives in Blender: add example, sculpt, apply (inversion), interpolate, preview, bake."""
import json

import numpy as np
import pytest

from support import shared
from blender_support import SS, blend_fingerprint, bpy, evaluated, import_file
from shapespace.bridge import meshes, posespace, skin
from shapespace.core.blendshape import bounding_box_diagonal

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
    for i, (q, (sx, ex)) in enumerate(zip(poses, values)):
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
