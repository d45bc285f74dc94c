"""Issue #25: analytic Jacobian columns of shape-key sliders through linear-blend armature skinning.

Reference: Blender's own evaluation — central differences of the depsgraph-evaluated surface (a slider is
linear: its central difference is exact up to float32 rounding) with the jaw bone posed, so the columns are the
key deltas carried through the posed skinning, not the raw deltas.
"""
import numpy as np
import pytest

import rigs
from blender_support import bpy
from shapespace.bridge import rig as brig
from support import shared


def _head():
    return shared(*rigs.FACECAP.split("/"))


def _posed_hybrid():
    rig = rigs.hybrid_rig(_head())
    c = brig.read_controls(rig.controls)
    c[rig.controls.index("jaw rotation X")] = 0.3
    c[rig.controls.index("jaw rotation Z")] = -0.12
    for name in rigs.HYBRID_KEYS:                        # inside the slider ranges: central differences
        c[rig.controls.index(f"key {name}")] = 0.3 + 0.05 * rigs.HYBRID_KEYS.index(name)
    brig.apply_controls(rig.controls, c)
    return rig


def _central(ev, i, h):
    plus, minus = ev.c0.copy(), ev.c0.copy()
    plus[i] += h
    minus[i] -= h
    return (ev.evaluate(plus) - ev.evaluate(minus)).reshape(-1) / (2 * h)


def test_slider_columns_are_exact_through_the_posed_armature():
    rig = _posed_hybrid()
    pins = np.arange(0, len(rig.mesh.data.vertices), 7)
    diag = rigs.diagonal(rig.world_points())
    with brig.RigEvaluator(rig.mesh, rig.controls, pins) as ev:
        J = ev.jacobian(ev.c0)
        assert ev.analytic_reason == ""
        moved = 0
        for name in rigs.HYBRID_KEYS:
            k = rig.controls.index(f"key {name}")
            ref = _central(ev, k, 0.1)
            np.testing.assert_allclose(J[:, k], ref, atol=1e-5 * diag)
            base = np.array([rig.mesh.data.shape_keys.key_blocks[name].data[i].co for i in pins])
            raw = (np.array([rig.mesh.data.shape_keys.key_blocks[0].data[i].co for i in pins]) - base)
            moved += np.abs(J[:, k].reshape(-1, 3) + raw @ np.array(rig.mesh.matrix_world)[:3, :3].T).max()
        assert moved > 1e-3 * diag                       # the posed jaw turns the deltas: not the raw deltas
        i = rig.controls.index("jaw rotation X")
        ref = _central(ev, i, 1e-2)
        np.testing.assert_allclose(J[:, i], ref, atol=2e-2 * np.abs(ref).max())
        evals = ev.evaluations
        ev.jacobian(ev.c0)
        assert ev.evaluations - evals <= 1 + 2           # one evaluation at c, one per bone channel
    with brig.RigEvaluator(rig.mesh, rig.controls, pins, analytic=False) as fd:
        Jfd = fd.jacobian(fd.c0)
        assert fd.analytic_reason == "off"
    np.testing.assert_allclose(J, Jfd, atol=2e-3 * diag)


def test_a_deformer_after_the_keys_or_a_driver_reading_them_falls_back_to_finite_differences():
    rig = _posed_hybrid()
    pins = np.arange(0, len(rig.mesh.data.vertices), 11)
    mod = rig.mesh.modifiers.new("Smooth", "SMOOTH")
    with brig.RigEvaluator(rig.mesh, rig.controls, pins) as ev:
        J = ev.jacobian(ev.c0)
        assert "'Smooth'" in ev.analytic_reason
        k = rig.controls.index("key browInnerUp")
        np.testing.assert_allclose(J[:, k], _central(ev, k, 0.1), atol=1e-3 * ev.controls.scale[k])
    rig.mesh.modifiers.remove(mod)
    kbs = rig.mesh.data.shape_keys.key_blocks
    fc = kbs["cheekPuff"].driver_add("value")
    var = fc.driver.variables.new()
    var.targets[0].id_type = "KEY"
    var.targets[0].id = rig.mesh.data.shape_keys
    var.targets[0].data_path = 'key_blocks["mouthFunnel"].value'
    fc.driver.expression = "var * 0.5"
    bpy.context.view_layer.update()
    with brig.RigEvaluator(rig.mesh, rig.controls.__class__(tuple(
            ch for ch in rig.controls.channels if ch.name != "key cheekPuff")), pins) as ev:
        J = ev.jacobian(ev.c0)
        assert ev.analytic_reason == "a driver reads a shape-key value"
        k = ev.controls.index("key mouthFunnel")
        np.testing.assert_allclose(J[:, k], _central(ev, k, 0.1), atol=1e-3 * ev.controls.scale[k])


def test_key_vertex_groups_and_relative_keys_are_honoured():
    rig = _posed_hybrid()
    kbs = rig.mesh.data.shape_keys.key_blocks
    kbs["mouthSmile_L"].vertex_group = "jaw"
    kbs["cheekPuff"].relative_key = kbs["mouthFunnel"]
    bpy.context.view_layer.update()
    pins = np.arange(0, len(rig.mesh.data.vertices), 5)
    with brig.RigEvaluator(rig.mesh, rig.controls, pins) as ev:
        J = ev.jacobian(ev.c0)
        assert ev.analytic_reason == ""
        diag = ev.diagonal
        for name in ("mouthSmile_L", "cheekPuff"):
            k = rig.controls.index(f"key {name}")
            ref = _central(ev, k, 0.1)
            assert np.abs(ref).max() > 1e-3 * diag
            np.testing.assert_allclose(J[:, k], ref, atol=1e-5 * diag)


def test_a_driven_slider_keeps_its_finite_difference_column():
    rig = _posed_hybrid()
    kbs = rig.mesh.data.shape_keys.key_blocks
    fc = kbs["mouthFunnel"].driver_add("value")
    fc.driver.expression = "0.25"
    bpy.context.view_layer.update()
    pins = np.arange(0, len(rig.mesh.data.vertices), 9)
    with brig.RigEvaluator(rig.mesh, rig.controls, pins, check=False) as ev:
        J = ev.jacobian(ev.c0)
        assert "mouthFunnel" in ev.analytic_reason
        assert np.abs(J[:, rig.controls.index("key mouthFunnel")]).max() == 0.0   # the driver overrides it
        k = rig.controls.index("key cheekPuff")
        np.testing.assert_allclose(J[:, k], _central(ev, k, 0.1), atol=1e-5 * rigs.diagonal(rig.world_points()))


def _bone_rig(mode):
    """The posed hybrid rig with the jaw in rotation ``mode``, its rotation channels and its three location
    channels; a child bone of the jaw (the lower lip) takes part of the jaw's weights, so a jaw channel moves a
    subtree."""
    rig = rigs.hybrid_rig(_head())
    arm = rig.armature
    bpy.context.view_layer.objects.active = arm
    bpy.ops.object.mode_set(mode="EDIT")
    jaw = arm.data.edit_bones["jaw"]
    lip = arm.data.edit_bones.new("lip")
    lip.head, lip.tail, lip.parent = jaw.tail, jaw.tail + (jaw.tail - jaw.head) * 0.3, jaw
    bpy.ops.object.mode_set(mode="OBJECT")
    group = rig.mesh.vertex_groups.new(name="lip")
    jaw_w = np.array([rig.mesh.vertex_groups["jaw"].weight(i) if any(g.group == rig.mesh.vertex_groups["jaw"].index
                                                                       for g in v.groups) else 0.0
                      for i, v in enumerate(rig.mesh.data.vertices)])
    for i in np.flatnonzero(jaw_w > 0.5):
        group.add([int(i)], float(jaw_w[i] - 0.4), "REPLACE")
    pb = arm.pose.bones["jaw"]
    for con in list(pb.constraints):
        pb.constraints.remove(con)
    pb.lock_rotation[1] = False
    pb.rotation_mode = mode
    lip_pb = arm.pose.bones["lip"]
    lip_pb.rotation_mode = "XYZ"
    lip_pb.rotation_euler = (0.2, -0.1, 0.15)
    lip_pb.location = (0.001, 0.002, -0.001)
    chans = [brig.bone_channel(arm, "jaw", "rotation", a) for a in range(3)]
    chans += [brig.bone_channel(arm, "jaw", "location", a) for a in range(3)]
    chans += [brig.bone_channel(arm, "lip", "rotation", 0), brig.bone_channel(arm, "lip", "scale", 1)]
    chans += [ch for ch in rig.controls.channels if ch.kind == "shape_key"]
    controls = brig.control_set(chans)
    c = brig.read_controls(controls)
    c[:8] = [0.25, -0.1, 0.12, 0.002, -0.003, 0.001, 0.1, 1.1]
    brig.apply_controls(controls, c)
    return rig, controls


@pytest.mark.parametrize("mode", ["XYZ", "ZXY", "QUATERNION", "AXIS_ANGLE"])
def test_bone_columns_match_blenders_central_differences_and_cost_one_evaluation(mode):
    rig, controls = _bone_rig(mode)
    pins = np.arange(0, len(rig.mesh.data.vertices), 7)
    with brig.RigEvaluator(rig.mesh, controls, pins) as ev:
        evals = ev.evaluations
        J = ev.jacobian(ev.c0)
        assert ev.evaluations - evals <= 1                        # one evaluation at c, no finite differences
        assert ev.analytic_reason == ""
        for i in range(8):
            h = 1e-3 if controls.channels[i].kind == "location" else 1e-2
            ref = _central(ev, i, h)
            assert np.abs(ref).max() > 1e-4 * ev.diagonal, controls.channels[i].name      # it moves the pins
            # central differences of float32 positions: truncation O(h²) and rounding ~1e-7 / h of the diagonal
            np.testing.assert_allclose(J[:, i], ref, atol=2e-3 * np.abs(ref).max(), err_msg=controls.channels[i].name)


def test_a_constrained_bone_or_a_driver_on_the_armature_keeps_finite_differences():
    rig, controls = _bone_rig("XYZ")
    pins = np.arange(0, len(rig.mesh.data.vertices), 13)
    con = rig.armature.pose.bones["lip"].constraints.new("COPY_ROTATION")
    con.target = rig.armature
    con.subtarget = "jaw"
    con.influence = 0.5
    bpy.context.view_layer.update()
    with brig.RigEvaluator(rig.mesh, controls, pins) as ev:
        J = ev.jacobian(ev.c0)
        assert "bones: bone 'lip' has a COPY_ROTATION constraint" in ev.analytic_reason
        np.testing.assert_allclose(J[:, 0], _central(ev, 0, 1e-2), atol=2e-2 * np.abs(J[:, 0]).max())
    rig.armature.pose.bones["lip"].constraints.remove(con)
    kbs = rig.mesh.data.shape_keys.key_blocks
    rigs._driver(kbs["cheekPuff"], "var", rig.armature, {"bone": "jaw", "transform": "ROT_X"})
    bpy.context.view_layer.update()
    with brig.RigEvaluator(rig.mesh, controls, pins, check=False) as ev:
        ev.jacobian(ev.c0)
        assert "bones: a driver reads or drives 'FaceRig'" in ev.analytic_reason
