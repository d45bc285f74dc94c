"""Core LBS/DQS equals Blender's Armature modifier on random poses of the shared skinned characters."""
import numpy as np
import pytest

from blender_support import bpy, evaluated, import_file, rel_error
from shapespace.bridge import meshes, shapekeys, skin
from shapespace.core import skinning
from shapespace.core.blendshape import bounding_box_diagonal
from support import shared

TOL = 1e-5

CHARACTERS = [
    ("cesium_man", "CesiumMan.glb"),
    ("robot_expressive", "RobotExpressive.glb"),
    ("rigged_simple", "RiggedSimple.glb"),
    ("rpm_brunette", "brunette-t.glb"),
]


def _random_pose(arm, rng, scale=False):
    b = len(arm.pose.bones)
    q = np.concatenate([np.ones((b, 1)), rng.normal(0, 0.35, (b, 3))], axis=1)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    s = None
    if scale:
        s = np.repeat(rng.uniform(0.7, 1.4, (b, 1)), 3, axis=1)  # uniform per bone
    skin.set_pose_basis(arm, rotations=q, locations=rng.normal(0, 0.05, (b, 3)), scales=s)


def _rest_input(obj):
    if obj.data.shape_keys:
        return shapekeys.read_blendshape_model(obj).evaluate()
    return meshes.vertex_positions(obj.data).astype(np.float64)


def _skinned():
    return [ob for ob in bpy.data.objects if ob.type == "MESH" and skin.armature_modifiers(ob)]


@pytest.mark.parametrize("asset", CHARACTERS, ids=[a[0] for a in CHARACTERS])
@pytest.mark.parametrize("preserve_volume", [False, True], ids=["lbs", "dqs"])
@pytest.mark.parametrize("scale", [False, True], ids=["rigid", "scaled"])
def test_random_poses_match_armature_modifier(asset, preserve_volume, scale):
    import_file(shared(*asset))
    rng = np.random.default_rng(7)
    objs = _skinned()
    assert objs
    for ob in objs:
        for m in skin.armature_modifiers(ob):
            m.use_deform_preserve_volume = preserve_volume
    for _ in range(3):
        arms = {m.object for ob in objs for m in skin.armature_modifiers(ob)}
        for arm in arms:
            _random_pose(arm, rng, scale)
        bpy.context.view_layer.update()
        # The model is the whole posed character: errors are relative to the world-space diagonal
        # of all its skinned meshes (a character's teeth are not a separate "model").
        diag = bounding_box_diagonal(np.concatenate([meshes.to_world(ob, evaluated(ob)) for ob in objs]))
        for ob in objs:
            rig = skin.read_skinning(ob)
            ours = skinning.deform(_rest_input(ob), rig, skin.modifier_poses(ob))
            world = np.linalg.norm(meshes.world_matrix(ob)[:3, :3], axis=0).max()
            err = np.abs(ours - evaluated(ob)).max() * world / diag
            assert err < TOL, f"{ob.name}: {err:.3g} abs {np.abs(ours - evaluated(ob)).max():.3g} diag {diag:.3g}"


def test_two_armature_modifiers_mask_and_nondeform_bones():
    """A stack of two Armature modifiers, a modifier vertex-group mask and a non-deforming bone."""
    import_file(shared("cesium_man", "CesiumMan.glb"))
    ob = bpy.data.objects["Cesium_Man"]
    arm = bpy.data.objects["Armature"]
    arm2 = arm.copy()
    arm2.data = arm.data.copy()
    bpy.context.scene.collection.objects.link(arm2)
    arm2.location = (0.1, 0.0, 0.2)
    second = ob.modifiers.new("Armature2", "ARMATURE")
    second.object = arm2
    second.use_deform_preserve_volume = True
    mask = ob.vertex_groups.new(name="half")
    mask.add(list(range(0, len(ob.data.vertices), 2)), 0.6, "REPLACE")
    second.vertex_group = "half"
    second.invert_vertex_group = True
    arm.data.bones[3].use_deform = False
    rng = np.random.default_rng(11)
    for a in (arm, arm2):
        _random_pose(a, rng)
    bpy.context.view_layer.update()
    rig = skin.read_skinning(ob)
    assert len(rig.deformers) == 2
    ours = skinning.deform(_rest_input(ob), rig, skin.modifier_poses(ob))
    assert rel_error(ours, evaluated(ob)) < TOL


def test_orphan_groups_and_unnormalised_weights_are_reported_and_still_exact():
    import_file(shared("rigged_simple", "RiggedSimple.glb"))
    ob = bpy.data.objects["Cylinder"]
    ghost = ob.vertex_groups.new(name="NoSuchBone")
    ghost.add(list(range(50)), 1.0, "REPLACE")
    # scale one bone's weights so sums are not 1, and zero a few vertices entirely
    g0 = ob.vertex_groups[0]
    g0.add(list(range(0, 200)), 0.05, "REPLACE")
    for g in ob.vertex_groups:
        if g.name != "NoSuchBone":
            g.remove([900, 901, 902])
    codes = {i.code for i in skin.check_skinning(ob)}
    assert "orphan_groups" in codes
    rig = skin.read_skinning(ob)
    diag = skinning.diagnose_weights(rig.deformers[0].weights)
    assert diag.diagnostics["unweighted"] >= 3
    assert diag.diagnostics["unnormalised"] > 0
    _random_pose(bpy.data.objects["Armature"], np.random.default_rng(3))
    bpy.context.view_layer.update()
    ours = skinning.deform(_rest_input(ob), rig, skin.modifier_poses(ob))
    blender = evaluated(ob)
    assert rel_error(ours, blender) < TOL
    rest = _rest_input(ob)
    np.testing.assert_allclose(blender[[900, 901, 902]], rest[[900, 901, 902]], atol=1e-6)


def test_pose_matrices_follow_bone_order():
    import_file(shared("cesium_man", "CesiumMan.glb"))
    arm = bpy.data.objects["Armature"]
    _random_pose(arm, np.random.default_rng(4))
    bpy.context.view_layer.update()
    mats = skin.pose_matrices(arm)
    for i, bone in enumerate(arm.data.bones):
        np.testing.assert_allclose(mats[i], np.array(arm.pose.bones[bone.name].matrix), atol=1e-6)
