"""Driven in-betweens and combinations follow key renames (issue #10, r10): the drivers are the truth."""
import numpy as np
import pytest

from blender_support import bpy, evaluated, rel_error, sphere_rig
from shapespace.bridge import driven, shapekeys

HOSTILE = 'b*__import__("os").system("x") \\ "q"'


def _rig():
    ob = sphere_rig(keys=5)
    bpy.context.view_layer.objects.active = ob
    return ob


@pytest.mark.parametrize("new_primary", ["Jaw", HOSTILE])
def test_renamed_primary_inbetween_and_combination_are_still_driven_keys(registered, new_primary):
    ob = _rig()
    ib = driven.add_inbetween(ob, "K0", "K3", 0.5)
    combo = driven.add_combination(ob, ["K0", "K1"], "K4")
    ob.data.shape_keys.key_blocks["K0"].name = new_primary
    ob.data.shape_keys.key_blocks[ib].name = "InBetweenRenamed"
    ob.data.shape_keys.key_blocks[combo].name = "ComboRenamed"
    meta = driven.prune(ob.data.shape_keys)
    assert meta["inbetweens"] == {"InBetweenRenamed": {"primary": new_primary, "at": 0.5}}
    assert meta["combinations"] == {"ComboRenamed": {"inputs": [new_primary, "K1"]}}
    assert shapekeys.slider_names(ob) == [new_primary, "K1", "K2"]
    # the model ShapeSpace reads evaluates as Blender does at a setting that exercises both driven keys
    model = shapekeys.read_blendshape_model(ob)
    w = np.array([0.3, 0.7, 0.2])
    shapekeys.write_slider_values(ob, model.names, w)
    assert rel_error(model.evaluate(w), evaluated(ob)) < 1e-6


def test_a_new_inbetween_after_a_rename_keeps_the_knots_of_the_old_one(registered):
    ob = _rig()
    driven.add_inbetween(ob, "K0", "K3", 0.5)
    ob.data.shape_keys.key_blocks["K0"].name = "Jaw"
    driven.add_inbetween(ob, "Jaw", "K4", 0.25)
    meta = driven.prune(ob.data.shape_keys)
    assert sorted(v["at"] for v in meta["inbetweens"].values()) == [0.25, 0.5]
    assert {v["primary"] for v in meta["inbetweens"].values()} == {"Jaw"}
    assert driven.knots_for(meta, "Jaw") == {"Jaw@0.25": (0.0, 0.25, 0.5), "K0@0.5": (0.25, 0.5, 1.0)}


def test_a_removed_driver_makes_the_key_a_plain_slider(registered):
    ob = _rig()
    ib = driven.add_inbetween(ob, "K0", "K3", 0.5)
    ob.data.shape_keys.key_blocks[ib].driver_remove("value")
    assert ib in shapekeys.slider_names(ob)
