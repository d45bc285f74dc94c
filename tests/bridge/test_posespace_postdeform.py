"""Post-deformation correctives (issue #16 Build 3): frame offsets applied after the armature by a generated
Geometry Nodes modifier.  Exact at the example pose, playback without the add-on equals the live preview,
re-weighting keeps them without re-inversion, topology-changing modifiers are refused.

Every check is Blender's own depsgraph evaluation.
"""
import numpy as np
import pytest

from blender_support import SS, blend_fingerprint, bpy, evaluated, import_file
from shapespace.bridge import meshes
from shapespace.bridge.posespace import finalshape, postdeform
from shapespace.core.blendshape import bounding_box_diagonal
from support import shared

TOL = 1e-5
QS = ((0.9, 0.3, 0.2, 0.1), (0.9, -0.3, 0.1, 0.2))


def _cesium():
    import_file(shared("cesium_man", "CesiumMan.glb"))
    ob = bpy.data.objects["Cesium_Man"]
    arm = bpy.data.objects["Armature"]
    arm.animation_data.action = None
    for pb in arm.pose.bones:
        pb.rotation_mode = "QUATERNION"
        pb.rotation_quaternion = (1, 0, 0, 0)
    bpy.context.view_layer.objects.active = ob
    return ob, arm, arm.pose.bones[5].name


def _pose(arm, bone, q):
    arm.pose.bones[bone].rotation_quaternion = q
    bpy.context.view_layer.update()


def _sculpt(ob, example, seed, amount=0.01):
    copy = ob.shapespace_psd.examples[example].sculpt
    co = meshes.vertex_positions(copy.data).astype(np.float64)
    moved = np.abs(co - meshes.vertex_positions(ob.data)).max(axis=1)
    rng = np.random.default_rng(seed)
    centre = co[int(np.argmax(moved))]
    size = bounding_box_diagonal(co)
    fall = np.exp(-np.sum((co - centre) ** 2, axis=1) / (0.06 * size) ** 2)
    co = co + amount * size * fall[:, None] * rng.normal(size=3)
    copy.data.vertices.foreach_set("co", co.astype(np.float32).ravel())
    copy.data.update()
    return meshes.to_local(ob, meshes.to_world(copy, co))


def _examples(ob, arm, bone, post=(True, False)):
    """Two examples of one bone; ``post[k]``: example k as a post-deformation corrective.  Wanted positions."""
    st = ob.shapespace_psd
    wanted = []
    for k, q in enumerate(QS):
        _pose(arm, bone, q)
        assert bpy.ops.shapespace.psd_add_example() == {"FINISHED"}
        st.active_example = k
        wanted.append(_sculpt(ob, st.examples[k].name, 30 + k))
        op = bpy.ops.shapespace.apply_post_deform if post[k] else bpy.ops.shapespace.psd_apply_example
        assert op(remove_copy=True) == {"FINISHED"}
    return wanted


def test_exact_at_the_pose_and_baked_playback_without_the_add_on_equals_the_preview(registered, tmp_path):
    ob, arm, bone = _cesium()
    wanted = _examples(ob, arm, bone)
    st = ob.shapespace_psd
    name = st.examples[0].name
    assert ob.modifiers[-1].name == postdeform.MODIFIER and ob.modifiers[-1].type == "NODES"
    assert ob.data.shape_keys.key_blocks[name].mute
    assert postdeform.attribute_name(name) in ob.data.attributes
    for k, q in enumerate(QS):                                  # Update Correctives at each example's pose
        _pose(arm, bone, q)
        assert bpy.ops.shapespace.psd_update() == {"FINISHED"}
        got = evaluated(ob)
        assert np.abs(got - wanted[k]).max() / bounding_box_diagonal(wanted[k]) < TOL, k
    # live preview through an animation, then bake and play the file back without the add-on
    pb = arm.pose.bones[bone]
    scene = bpy.context.scene
    for f, q in ((1, (1, 0, 0, 0)), (10, QS[0]), (20, QS[1])):
        pb.rotation_quaternion = q
        pb.keyframe_insert("rotation_quaternion", frame=f)
    st.live_preview = True
    preview = {}
    for f in (5, 10, 15, 20):
        scene.frame_set(f)
        preview[f] = evaluated(ob)
    st.live_preview = False
    assert np.abs(preview[10] - wanted[0]).max() / bounding_box_diagonal(wanted[0]) < TOL
    plain_between = preview[5]
    assert bpy.ops.shapespace.psd_bake(frame_start=1, frame_end=20) == {"FINISHED"}
    path = str(tmp_path / "postdeform.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    SS.unregister()
    try:
        bpy.ops.wm.open_mainfile(filepath=path)
        ob2 = bpy.data.objects["Cesium_Man"]
        assert ob2.modifiers[-1].name == postdeform.MODIFIER
        for f, want in preview.items():
            bpy.context.scene.frame_set(f)
            got = evaluated(ob2)
            assert np.abs(got - want).max() / bounding_box_diagonal(want) < TOL, f
        bpy.context.scene.frame_set(5)
        assert np.abs(evaluated(ob2) - plain_between).max() < 1e-6 * bounding_box_diagonal(plain_between)
    finally:
        SS.register()


def test_reweighting_keeps_the_offsets_without_reinversion(registered):
    ob, arm, bone = _cesium()
    st = ob.shapespace_psd
    _pose(arm, bone, QS[0])
    assert bpy.ops.shapespace.psd_add_example() == {"FINISHED"}
    wanted = _sculpt(ob, st.examples[0].name, 3)
    assert bpy.ops.shapespace.apply_post_deform(remove_copy=True) == {"FINISHED"}
    name = st.examples[0].name
    blocks = ob.data.shape_keys.key_blocks
    blocks[name].value = 0.0
    plain_old = evaluated(ob)
    offset_old = np.linalg.norm(wanted - plain_old, axis=1)
    moved = np.flatnonzero(offset_old > 1e-4 * bounding_box_diagonal(wanted))
    assert len(moved) > 20
    for v in moved:                                           # re-weight every sculpted vertex shared by two bones
        groups = ob.data.vertices[int(v)].groups
        if len(groups) > 1:
            g = max(groups, key=lambda g: g.weight)
            ob.vertex_groups[g.group].add([int(v)], g.weight * 0.3, "REPLACE")
    plain_new = evaluated(ob)
    assert np.abs(plain_new - plain_old).max() > 1e-3 * bounding_box_diagonal(wanted)
    blocks[name].value = 1.0
    got = evaluated(ob)
    size = bounding_box_diagonal(wanted)
    # the corrective rides on the re-weighted surface: same offset lengths, no re-inversion, nothing stale
    assert np.abs(np.linalg.norm(got - plain_new, axis=1) - offset_old).max() / size < TOL
    assert finalshape.stale_examples(ob) == []


def test_topology_changing_modifier_and_weighted_psd_are_refused(registered):
    ob, arm, bone = _cesium()
    st = ob.shapespace_psd
    _pose(arm, bone, QS[0])
    assert bpy.ops.shapespace.psd_add_example() == {"FINISHED"}
    _sculpt(ob, st.examples[0].name, 4)
    mod = ob.modifiers.new("Smooth It", "SUBSURF")
    mod.levels = 1
    before = blend_fingerprint()
    with pytest.raises(RuntimeError, match="'Smooth It'.*changes the topology"):
        bpy.ops.shapespace.apply_post_deform()
    assert blend_fingerprint() == before
    assert postdeform.MODIFIER not in ob.modifiers and not st.examples[0].post_deform
    ob.modifiers.remove(mod)
    st.method = "WPSD"
    with pytest.raises(RuntimeError, match="per-example weight"):
        bpy.ops.shapespace.apply_post_deform()
    st.method = "SBE"
    assert bpy.ops.shapespace.apply_post_deform() == {"FINISHED"}
    # removing the last post-deformation example removes what was generated for it
    assert bpy.ops.shapespace.psd_remove_example() == {"FINISHED"}
    assert postdeform.MODIFIER not in ob.modifiers
    assert not [a.name for a in ob.data.attributes if a.name.startswith("ss_pd_PSD")]
