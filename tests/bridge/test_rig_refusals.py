"""Issue #25 bad input: each refused by name before any solve, the rig left exactly as it was, nothing keyed."""
import os
import tempfile

import numpy as np
import pytest

import rigs
from blender_support import bpy
from shapespace.bridge import rig as brig
from shapespace.core.result import ShapeSpaceError
from support import shared


def _head():
    return shared(*rigs.FACECAP.split("/"))


def _snapshot(rig, controls):
    raw = [b.raw() for b in brig.bind(controls)]
    return raw, len(bpy.data.actions), rig.world_points()


def _refused(rig, controls, code, *names, pins=(0, 1, 2), same_surface=True):
    """Opening an evaluator (and the solve) on ``controls`` raises ``code`` naming ``names``; nothing changes
    (the evaluated surface too, unless the rig is not deterministic)."""
    before = _snapshot(rig, controls)
    targets = rig.world_points()[list(pins)]
    with pytest.raises(ShapeSpaceError) as exc:
        brig.solve_pins(rig.mesh, controls, list(pins), targets)
    assert exc.value.code == code, str(exc.value)
    for name in names:
        assert name in str(exc.value), str(exc.value)
    assert "\n" not in str(exc.value)
    after = _snapshot(rig, controls)
    assert before[:2] == after[:2]
    if same_surface:
        np.testing.assert_array_equal(before[2], after[2])
    return str(exc.value)


def test_channel_that_moves_nothing_is_refused_by_name():
    rig = rigs.hybrid_rig(_head())
    cs = brig.control_set(list(rig.controls.channels) + [brig.shape_key_channel(rig.mesh, "tongueOut")])
    _refused(rig, cs, "degenerate", "key tongueOut")                 # facecap's empty target


def test_driven_slider_moves_nothing_and_is_refused():
    rig = rigs.driver_rig(_head())
    cs = brig.control_set(list(rig.controls.channels) + [brig.shape_key_channel(rig.mesh, "jawOpen")])
    _refused(rig, cs, "degenerate", "key jawOpen")                   # its driver overrides any value


def test_locked_channel_is_refused_by_name():
    rig = rigs.hybrid_rig(_head())
    cs = brig.control_set(list(rig.controls.channels) + [brig.bone_channel(rig.armature, "jaw", "rotation", 1)])
    _refused(rig, cs, "invalid", "jaw rotation Y", "locked")


def test_channel_constrained_away_is_refused_by_name():
    rig = rigs.hybrid_rig(_head())
    con = rig.armature.pose.bones["jaw"].constraints[0]
    con.min_z = con.max_z = 0.0
    cs = brig.control_set([brig.bone_channel(rig.armature, "jaw", "rotation", a) for a in (0, 2)])
    _refused(rig, cs, "invalid", "jaw rotation Z", "held still")


def test_non_deterministic_rig_is_refused():
    rig = rigs.driver_rig(_head())
    rng = np.random.default_rng(0)
    bpy.app.driver_namespace["ss_test_noise"] = lambda: float(rng.random())
    try:
        rigs._driver(rig.mesh.data.shape_keys.key_blocks["cheekPuff"], "var + ss_test_noise()", rig.armature,
                     {"prop": "blink"})
        bpy.context.view_layer.update()
        _refused(rig, rig.controls, "invalid", "Mesh_2", "not evaluate the same twice",
                 same_surface=False)
    finally:
        del bpy.app.driver_namespace["ss_test_noise"]


def test_driver_that_raises_is_refused_by_name():
    rig = rigs.driver_rig(_head())
    rigs._driver(rig.mesh.data.shape_keys.key_blocks["cheekPuff"], "no_such_function(var)", rig.armature,
                 {"prop": "blink"})
    msg = _refused(rig, rig.controls, "invalid", 'key_blocks["cheekPuff"].value', "no_such_function")
    assert "driver" in msg


@pytest.mark.parametrize("which", ["mesh", "armature"])
def test_edit_mode_is_refused(which):
    rig = rigs.hybrid_rig(_head())
    ob = rig.mesh if which == "mesh" else rig.armature
    bpy.context.view_layer.objects.active = ob
    bpy.ops.object.mode_set(mode="EDIT")
    with pytest.raises(ShapeSpaceError, match="Edit Mode") as exc:
        brig.solve_pins(rig.mesh, rig.controls, [0, 1], np.zeros((2, 3)))
    assert exc.value.code == "mode" and ob.name in str(exc.value)
    assert ob.mode == "EDIT"


def _linked_rig(override: bool):
    rig = rigs.hybrid_rig(_head())
    path = os.path.join(tempfile.mkdtemp(prefix="ss-rig-"), "rig.blend")
    names = [rig.mesh.name, rig.armature.name]
    bpy.data.libraries.write(path, {rig.mesh, rig.armature}, fake_user=True)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    with bpy.data.libraries.load(path, link=True) as (_, dst):
        dst.objects = names
    for ob in dst.objects:
        bpy.context.scene.collection.objects.link(ob)
    mesh, arm = bpy.data.objects["Mesh_2"], bpy.data.objects["FaceRig"]
    if override:
        arm = arm.override_create(remap_local_usages=True)
        mesh = mesh.override_create(remap_local_usages=True)
    return mesh, arm


@pytest.mark.parametrize("override", [False, True], ids=["linked", "override"])
def test_linked_or_overridden_rig_is_refused(override):
    mesh, arm = _linked_rig(override)
    cs = brig.control_set([brig.bone_channel(arm, "jaw", "rotation", 0), brig.shape_key_channel(mesh, "eyeBlink_L")])
    before = brig.read_controls(cs)
    with pytest.raises(ShapeSpaceError, match="library override" if override else "linked") as exc:
        brig.solve_pins(mesh, cs, [0, 1], np.zeros((2, 3)))
    assert exc.value.code == "linked" and "Mesh_2" in str(exc.value)
    np.testing.assert_array_equal(brig.read_controls(cs), before)


def test_pins_outside_the_mesh_and_values_outside_bounds_are_refused():
    rig = rigs.hybrid_rig(_head())
    n = len(rig.mesh.data.vertices)
    with pytest.raises(ShapeSpaceError, match=f"vertex {n}") as exc:
        brig.solve_pins(rig.mesh, rig.controls, [0, n], np.zeros((2, 3)))
    assert exc.value.code == "pin"
    c = brig.read_controls(rig.controls)
    c[0] = 2.0
    with pytest.raises(ShapeSpaceError, match="jaw rotation X") as exc:
        brig.apply_controls(rig.controls, c)
    assert exc.value.code == "range"


def test_modifier_that_changes_the_vertex_count_is_refused():
    rig = rigs.hybrid_rig(_head())
    rig.mesh.modifiers.new("Subdivision", "SUBSURF")
    _refused(rig, rig.controls, "topology_modifiers", "Mesh_2", "vertex count")
