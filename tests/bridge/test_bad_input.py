"""Issue #2 bad input: each case gives a clear message and leaves the .blend unchanged."""
import numpy as np
import pytest

from blender_support import blend_fingerprint, bpy, import_file, sphere_rig
from shapespace.bridge import inventory, shapekeys, skin
from shapespace.core.blendshape import diagnose_model
from shapespace.core.result import ShapeSpaceError
from support import shared


def _sphere(keys=0, name="Face"):
    return sphere_rig(keys, name)


def _set_key(ob, name, coords):
    ob.data.shape_keys.key_blocks[name].data.foreach_set("co", np.asarray(coords, np.float32).ravel())


def _key(ob, name):
    kb = ob.data.shape_keys.key_blocks[name]
    co = np.empty(len(kb.data) * 3, np.float32)
    kb.data.foreach_get("co", co)
    return co.reshape(-1, 3)


def _run_check(ob):
    """Run the Check Rig operator; return (result, fingerprint unchanged)."""
    bpy.context.view_layer.objects.active = ob
    before = blend_fingerprint()
    try:
        result = bpy.ops.shapespace.check_rig()
    except RuntimeError as exc:  # operator reported ERROR: bpy raises with the message
        result = {"CANCELLED"}
        message = str(exc)
    else:
        message = ""
    return result, before == blend_fingerprint(), message


def _codes(ob):
    return {i.code: i for i in inventory.check_object(ob)}


def test_mesh_without_shape_keys(registered):
    ob = _sphere(0)
    codes = _codes(ob)
    assert "no_shape_keys" in codes and "'Face'" in codes["no_shape_keys"].message
    with pytest.raises(ShapeSpaceError, match="has no shape keys"):
        shapekeys.read_blendshape_model(ob)
    result, unchanged, message = _run_check(ob)
    assert result == {"CANCELLED"} and unchanged
    assert "has no shape keys" in message


def test_all_zero_target_is_reported_by_name(registered):
    ob = _sphere(3)
    _set_key(ob, "K1", _key(ob, "Basis"))
    codes = _codes(ob)
    assert codes["empty_target"].items == ("K1",)
    result, unchanged, _ = _run_check(ob)
    assert result == {"FINISHED"} and unchanged  # a warning, the rig is usable
    assert diagnose_model(shapekeys.read_blendshape_model(ob)).diagnostics["rank"] == 2


def test_facecap_tongue_out_is_empty():
    import_file(shared("facecap", "facecap_decoded.glb"))
    assert _codes(bpy.data.objects["Mesh_2"])["empty_target"].items == ("tongueOut",)


def test_duplicate_targets(registered):
    ob = _sphere(3)
    _set_key(ob, "K2", _key(ob, "K0"))
    issue = _codes(ob)["duplicate_target"]
    assert "K0 = K2" in issue.message
    result, unchanged, _ = _run_check(ob)
    assert result == {"FINISHED"} and unchanged


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_nan_and_inf_coordinates(registered, bad):
    ob = _sphere(2)
    co = _key(ob, "K1").copy()
    co[5, 1] = bad
    _set_key(ob, "K1", co)
    issue = _codes(ob)["non_finite"]
    assert issue.severity == "error" and "K1" in issue.message
    result, unchanged, message = _run_check(ob)
    assert result == {"CANCELLED"} and unchanged and "NaN or infinite" in message


def test_key_relative_to_non_basis(registered):
    ob = _sphere(2)
    blocks = ob.data.shape_keys.key_blocks
    blocks["K1"].relative_key = blocks["K0"]
    issue = _codes(ob)["relative_to_non_basis"]
    assert "K1 (relative to K0)" in issue.message
    model = shapekeys.read_blendshape_model(ob)
    np.testing.assert_allclose(model.deltas[1], _key(ob, "K1") - _key(ob, "K0"), atol=1e-6)
    result, unchanged, _ = _run_check(ob)
    assert result == {"FINISHED"} and unchanged


def test_vertex_count_changed_after_shape_keys(registered):
    ob = _sphere(2)
    ob.data.vertices.add(3)
    issue = _codes(ob)["vertex_count_mismatch"]
    assert "topology changed" in issue.message
    with pytest.raises(ShapeSpaceError, match="topology changed"):
        shapekeys.read_blendshape_model(ob)
    result, unchanged, message = _run_check(ob)
    assert result == {"CANCELLED"} and unchanged and "topology changed" in message


def _rigged_simple():
    import_file(shared("rigged_simple", "RiggedSimple.glb"))
    return bpy.data.objects["Cylinder"]


def test_vertex_groups_named_for_missing_bones(registered):
    ob = _rigged_simple()
    ob.vertex_groups.new(name="Tail").add([0, 1, 2], 1.0, "REPLACE")
    issue = _codes(ob)["orphan_groups"]
    assert "Tail" in issue.message and "ignored" in issue.message
    result, unchanged, _ = _run_check(ob)
    assert result == {"FINISHED"} and unchanged


def test_weights_not_summing_to_one_and_all_zero(registered):
    ob = _rigged_simple()
    for g in ob.vertex_groups:
        g.add([10, 11], 0.1, "REPLACE")   # sums 0.1 * groups present ≠ 1
        g.remove([20, 21, 22])            # no weight at all
    codes = _codes(ob)
    assert "3 vertices have no weight" in codes["unweighted_vertices"].message
    assert "do not sum to 1" in codes["unnormalised_weights"].message
    result, unchanged, _ = _run_check(ob)
    assert result == {"FINISHED"} and unchanged


def test_envelope_deform_is_refused_clearly(registered):
    ob = _rigged_simple()
    skin.armature_modifiers(ob)[0].use_bone_envelopes = True
    with pytest.raises(ShapeSpaceError, match="envelopes"):
        skin.read_skinning(ob)
    result, unchanged, message = _run_check(ob)
    assert result == {"CANCELLED"} and unchanged and "envelopes" in message


def test_check_rig_poll_explains_itself(registered):
    bpy.ops.object.empty_add()
    assert not bpy.ops.shapespace.check_rig.poll()
    assert not bpy.ops.shapespace.key_sliders.poll()
