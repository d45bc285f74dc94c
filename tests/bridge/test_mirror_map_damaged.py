"""A damaged mirror-map blob (``mesh["shapespace_mirror_map"]``, issue #13) in a .blend: Check Rig names it, every
operator ends refused, cancelled (one-line report, file unchanged) or finished soundly, and every panel draws.
A healthy or a stale map is not damage."""
import json

import pytest

from blender_support import OPERATOR_CALLS, bpy, classify_operator_call, sphere_rig
from shapespace.bridge import inventory, symmetry
from test_stored_data import DAMAGE, _draw_every_panel

PROP = symmetry.PROP


def _rig():
    ob = sphere_rig()
    for f in (1, 10, 20):
        for kb in ob.data.shape_keys.key_blocks[1:]:
            kb.value = f / 20
            kb.keyframe_insert("value", frame=f)
    bpy.context.view_layer.objects.active = ob
    ob.select_set(True)
    return ob


def _good_blob(ob):
    symmetry.store_map(ob, symmetry.build_map(ob, "POSITION"))
    return json.loads(ob.data[PROP])


def _not_a_table(ob):
    data = _good_blob(ob)
    data["mirror"][0] = len(ob.data.vertices) + 5                   # a vertex the mesh does not have
    return json.dumps(data)


def _not_an_involution(ob):
    data = _good_blob(ob)
    data["mirror"] = [0] * len(ob.data.vertices)                   # everyone's mirror is vertex 0
    return json.dumps(data)


def _bad_axis(ob):
    data = _good_blob(ob)
    data["axis"] = 7
    return json.dumps(data)


def _empty_table(ob):
    data = _good_blob(ob)
    data["mirror"] = []
    return json.dumps(data)


EXTRA = {"not_a_table": _not_a_table, "not_an_involution": _not_an_involution, "bad_axis": _bad_axis,
         "empty_table": _empty_table}
CASES = sorted(DAMAGE) + sorted(EXTRA)


def _damage(ob, damage):
    ob.data[PROP] = EXTRA[damage](ob) if damage in EXTRA else DAMAGE[damage]


@pytest.mark.parametrize("damage", CASES)
def test_check_rig_names_a_damaged_mirror_map(registered, damage):
    ob = _rig()
    _damage(ob, damage)
    found = [i for i in inventory.check_object(ob) if i.code == "corrupt_metadata"]
    assert found and PROP in found[0].message and "\n" not in found[0].message, found
    with pytest.raises(RuntimeError, match=f"damaged ShapeSpace data in Mesh '{ob.data.name}' ▸ {PROP}"):
        bpy.ops.shapespace.check_rig()


def test_a_healthy_or_stale_map_is_not_damage(registered):
    ob = _rig()
    assert bpy.ops.shapespace.build_mirror_map("EXEC_DEFAULT") == {"FINISHED"}
    assert symmetry.load_map(ob).coverage == 1.0
    assert not [i for i in inventory.check_object(ob) if i.code == "corrupt_metadata"]
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.select_all(action="DESELECT")
    bpy.ops.object.mode_set(mode="OBJECT")
    ob.data.vertices[0].select = True
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.delete(type="VERT")
    bpy.ops.object.mode_set(mode="OBJECT")
    assert symmetry.map_status(ob)["state"] == "stale"
    assert not [i for i in inventory.check_object(ob) if i.code == "corrupt_metadata"]


@pytest.mark.parametrize("damage", ["invalid_json", "wrong_types", "from_the_future", "not_an_involution"])
def test_every_operator_and_panel_survives_a_damaged_mirror_map(registered, damage):
    ob = _rig()
    bpy.ops.shapespace.add_pin(vertices=(3, 0, 0))                # so the pin operators get past their polls
    _damage(ob, damage)
    _draw_every_panel()
    bad = []
    for op_name, kwargs in sorted(OPERATOR_CALLS.items()):
        bpy.context.view_layer.objects.active = bpy.data.objects["Face"]
        outcome, message = classify_operator_call(op_name, kwargs)
        if outcome not in ("refused", "cancelled", "finished"):
            bad.append((op_name, outcome, message.splitlines()[-1] if message else ""))
    assert not bad, bad
    _draw_every_panel()
