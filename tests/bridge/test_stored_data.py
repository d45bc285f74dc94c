"""Damaged ShapeSpace data in a .blend (issue #10, r21): every stored blob, every kind of damage.

For each damaged blob: Check Rig names it (code ``corrupt_metadata``, the property in the message), every
operator ends refused, cancelled with a one-line report and the file unchanged, or finished soundly — never a
traceback — and every panel still draws.  Saving upgrades only readable blobs; damaged ones stay as they are.
"""
import json

import pytest

from blender_support import OPERATOR_CALLS, bpy, classify_operator_call, draw_panel, sphere_rig
from shapespace.bridge import inventory

KEY_BLOBS = ("shapespace_driven", "shapespace_mapping", "shapespace_last_retarget", "shapespace_representation",
             "shapespace_face_prior", "shapespace_analysis")
DAMAGE = {
    "invalid_json": "{not json",
    "not_an_object": "[1, 2, 3]",
    "wrong_types": json.dumps({"schema_version": 1, "inbetweens": [], "combinations": 3, "form": 7, "source": [],
                               "names": "x", "mean": {}, "JawOpen": "K0", "compression": 5, "coherence": "x"}),
    "missing_fields": json.dumps({"schema_version": 1}),
    "from_the_future": json.dumps({"schema_version": 99}),
    "deep_nesting": "[" * 5000 + "]" * 5000,
}


def _rig():
    ob = sphere_rig()
    for f in (1, 10, 20):
        for kb in ob.data.shape_keys.key_blocks[1:]:
            kb.value = f / 20
            kb.keyframe_insert("value", frame=f)
    bpy.context.view_layer.objects.active = ob
    ob.select_set(True)
    return ob


def _draw_every_panel():
    from shapespace.panels import classes
    for cls in classes:
        if not cls.__name__.startswith("SHAPESPACE_PT"):
            continue
        if hasattr(cls, "poll") and not cls.poll(bpy.context):
            continue
        draw_panel(cls, bpy.context, strict=False, bl_idname=cls.__name__)


#: blobs for which an empty object is valid (an empty mapping, no analysis yet)
EMPTY_IS_VALID = ("shapespace_mapping", "shapespace_analysis")
CASES = [(prop, damage) for prop in KEY_BLOBS for damage in sorted(DAMAGE)
         if not (damage == "missing_fields" and prop in EMPTY_IS_VALID)]


@pytest.mark.parametrize("prop,damage", CASES)
def test_check_rig_names_a_damaged_blob(registered, prop, damage):
    ob = _rig()
    ob.data.shape_keys[prop] = DAMAGE[damage]
    found = [i for i in inventory.check_object(ob) if i.code == "corrupt_metadata"]
    assert found and prop in found[0].message and "\n" not in found[0].message, found
    with pytest.raises(RuntimeError, match=f"damaged ShapeSpace data in Key 'Key' ▸ {prop}"):
        bpy.ops.shapespace.check_rig()


@pytest.mark.parametrize("damage", ["invalid_json", "wrong_types", "from_the_future"])
@pytest.mark.parametrize("prop", KEY_BLOBS)
def test_every_operator_and_panel_survives_a_damaged_blob(registered, prop, damage):
    ob = _rig()
    ob.data.shape_keys[prop] = DAMAGE[damage]
    _draw_every_panel()
    bad = []
    for op_name, kwargs in sorted(OPERATOR_CALLS.items()):
        bpy.context.view_layer.objects.active = bpy.data.objects["Face"]
        outcome, message = classify_operator_call(op_name, kwargs)
        if outcome not in ("refused", "cancelled", "finished"):
            bad.append((op_name, outcome, message.splitlines()[-1] if message else ""))
    assert not bad, bad
    _draw_every_panel()


def test_damaged_example_strings_are_named_and_nothing_breaks(registered):
    from support import ASSETS
    from blender_support import import_file
    import os
    import_file(os.path.join(ASSETS, "cesium_man", "CesiumMan.glb"))
    ob = next(o for o in bpy.data.objects if o.type == "MESH")
    arm = next(o for o in bpy.data.objects if o.type == "ARMATURE")
    if arm.animation_data:
        arm.animation_data.action = None
    bpy.context.view_layer.objects.active = ob
    pb = arm.pose.bones[len(arm.pose.bones) // 2]
    pb.rotation_mode = "QUATERNION"
    pb.rotation_quaternion = (0.9, 0.3, 0.2, 0.1)
    bpy.context.view_layer.update()
    assert bpy.ops.shapespace.psd_add_example() == {"FINISHED"}
    ex = ob.shapespace_psd.examples[0]
    for attr in ("pose", "target_values"):
        good = getattr(ex, attr)
        setattr(ex, attr, "{broken")
        found = [i for i in inventory.check_object(ob) if i.code == "corrupt_metadata"]
        assert found and attr in found[0].message and ex.name in found[0].message, found
        _draw_every_panel()
        for op_name in ("psd_update", "psd_apply_example", "psd_move_example", "psd_mirror_example", "psd_bake",
                        "psd_confidence", "psd_record_targets"):
            bpy.context.view_layer.objects.active = ob
            outcome, message = classify_operator_call(op_name, OPERATOR_CALLS[op_name])
            assert outcome in ("refused", "cancelled", "finished"), (attr, op_name, outcome, message)
        setattr(ex, attr, good)


def test_saving_keeps_a_damaged_blob_as_it_is_and_upgrades_the_rest(registered, tmp_path):
    ob = _rig()
    key = ob.data.shape_keys
    key["shapespace_mapping"] = "{not json"
    key["shapespace_driven"] = json.dumps({"inbetweens": {}, "combinations": {}})      # version 0 (0.1.0)
    path = str(tmp_path / "saved.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)
    key = bpy.data.objects["Face"].data.shape_keys
    assert key["shapespace_mapping"] == "{not json"
    assert json.loads(key["shapespace_driven"])["schema_version"] == 1
