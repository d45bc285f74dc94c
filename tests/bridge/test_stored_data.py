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
    import os

    from blender_support import import_file
    from support import ASSETS
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


# ----------------------------------------------------------------------------------------- the registry
# Every blob of core.blobs.BLOBS, on the owner it names: saving upgrades an old one, Check Rig names a damaged one.
from shapespace.bridge import actions  # noqa: E402
from shapespace.core import blobs  # noqa: E402
from shapespace.core.schema import Schema, loads  # noqa: E402

_SAMPLE = {"object": {}, "list": [], "string": "x", "number": 1.5, "int": 2, "bool": True}


def _version_0(schema) -> str:
    """A blob as ShapeSpace 0.1.0 wrote it (no schema_version; a bare JSON list for list blobs)."""
    if schema.list_blob:
        return json.dumps([0.25, 0.5])
    data = {name: _SAMPLE[kind.rstrip("?")] for name, kind in schema.fields.items()}
    if schema.values is not None:
        data["jawOpen"] = _SAMPLE[schema.values]
    return json.dumps(data)


def _owners():
    """A mesh object with shape keys, one pose-space example and a take action its shape keys play:
    ``{owner kind: owner}``."""
    ob = _rig()
    ex = ob.shapespace_psd.examples.add()
    ex.name = "PSD_01"
    act = bpy.data.actions.new("Take 1")
    act.use_fake_user = True
    actions.assign_action(ob.data.shape_keys, act)
    return ob, {"Object": ob, "Mesh": ob.data, "Key": ob.data.shape_keys, "Action": act, "Example": ex}


def _put(owner, blob, text):
    if blob.on_id:
        owner[blob.prop] = text
    else:
        setattr(owner, blob.prop, text)


def _reopened(kind):
    ob = bpy.data.objects["Face"]
    return {"Object": ob, "Mesh": ob.data, "Key": ob.data.shape_keys, "Action": bpy.data.actions["Take 1"],
            "Example": ob.shapespace_psd.examples["PSD_01"]}[kind]


def test_the_owners_are_real_blender_types():
    ob, owners = _owners()
    assert set(owners) == set(blobs.OWNERS)
    assert {k: type(v).__name__ for k, v in owners.items() if k in blobs.ID_OWNERS} == \
        {k: k for k in blobs.ID_OWNERS}
    for blob in blobs.BLOBS:
        if not blob.on_id:
            assert isinstance(getattr(owners[blob.owner], blob.prop), str), blob.prop


@pytest.mark.parametrize("blob", blobs.BLOBS, ids=lambda b: f"{b.owner}.{b.prop}")
def test_saving_upgrades_an_old_blob_of_every_registered_kind(registered, tmp_path, blob):
    ob, owners = _owners()
    old = _version_0(blob.schema)
    _put(owners[blob.owner], blob, old)
    path = str(tmp_path / "saved.blend")
    assert bpy.ops.wm.save_as_mainfile(filepath=path) == {"FINISHED"}
    assert bpy.ops.wm.open_mainfile(filepath=path) == {"FINISHED"}
    owner = _reopened(blob.owner)
    text = owner[blob.prop] if blob.on_id else getattr(owner, blob.prop)
    assert json.loads(text)["schema_version"] == blob.schema.version
    assert loads(text, blob.schema, "saved") == loads(old, blob.schema, "0.1.0")


@pytest.mark.parametrize("blob", blobs.BLOBS, ids=lambda b: f"{b.owner}.{b.prop}")
def test_check_rig_names_a_damaged_blob_of_every_registered_kind(registered, blob):
    ob, owners = _owners()
    _put(owners[blob.owner], blob, "{not json")
    found = [i for i in inventory.check_object(ob) if i.code == "corrupt_metadata"]
    assert len(found) == 1 and blob.prop in found[0].message and owners[blob.owner].name in found[0].message, found
    with pytest.raises(RuntimeError, match=f"damaged ShapeSpace data in .* ▸ {blob.prop}"):
        bpy.ops.shapespace.check_rig()


@pytest.mark.parametrize("section", ["compression", "coherence"])
def test_check_rig_names_a_damaged_report_inside_the_analysis(registered, section):
    ob = _rig()
    ob.data.shape_keys[blobs.ANALYSIS.prop] = json.dumps({"schema_version": 1, section: {"targets": "many"}})
    found = [i for i in inventory.check_object(ob) if i.code == "corrupt_metadata"]
    assert len(found) == 1 and f"{blobs.ANALYSIS.prop} ▸ {section}" in found[0].message, found


def test_every_schema_of_every_module_of_the_add_on_is_registered(registered):
    """Walk every module of the add-on (imported): each Schema it holds, at module level or in a module-level
    dict, list or tuple, is one registered in core.blobs (the same object)."""
    import importlib
    import pkgutil

    import shapespace
    registered_ids = {id(s) for s in blobs.schemas()}
    seen, stray = 0, []
    for info in pkgutil.walk_packages(shapespace.__path__, "shapespace."):
        if info.name.startswith("shapespace.tests"):
            continue
        module = importlib.import_module(info.name)
        for name, value in vars(module).items():
            inner = value.values() if isinstance(value, dict) else value if isinstance(value, (list, tuple)) else ()
            for item in [value, *inner]:
                if isinstance(item, Schema):
                    seen += 1
                    if id(item) not in registered_ids:
                        stray.append(f"{info.name}.{name}")
    assert not stray, f"Schemas not in core.blobs.BLOBS: {stray}"
    assert seen >= len(registered_ids)
