"""In-between and combination shapes built with native drivers evaluate exactly as the core model."""
import os

import numpy as np
import pytest

from blender_support import blend_fingerprint, bpy, evaluated, import_file, rel_error
from shapespace.bridge import driven, shapekeys
from shapespace.core.manipulation import Pin, pin_positions, solve_drag
from shapespace.core.result import ShapeSpaceError
from support import ASSETS


def _facecap():
    import_file(os.path.join(ASSETS, "facecap", "facecap_decoded.glb"))
    ob = bpy.data.objects["Mesh_2"]
    ob.data.shape_keys.animation_data_clear()
    return ob


def _sculpt(ob, name, from_keys, extra, rng):
    """A new full shape: a mix of existing keys plus a smooth random bulge (an artist's sculpt)."""
    model = shapekeys.read_blendshape_model(ob)
    w = np.zeros(model.n_targets)
    for n, v in from_keys.items():
        w[model.index(n)] = v
    pos = model.evaluate(w)
    centre = pos[rng.integers(len(pos))]
    fall = np.exp(-np.sum((pos - centre) ** 2, axis=1) / (0.05 * model.scale) ** 2)
    pos = pos + extra * model.scale * fall[:, None] * rng.normal(size=3)
    shapekeys.add_shape_key(ob, name, pos)
    return pos


def test_inbetweens_and_combinations_match_blender_and_play_without_python(registered):
    ob = _facecap()
    rng = np.random.default_rng(0)
    _sculpt(ob, "jawHalf", {"jawOpen": 0.5}, 0.02, rng)
    ib = driven.add_inbetween(ob, "jawOpen", "jawHalf", 0.5)
    _sculpt(ob, "jawQuarter", {"jawOpen": 0.25}, 0.01, rng)
    driven.add_inbetween(ob, "jawOpen", "jawQuarter", 0.25)
    sculpt = _sculpt(ob, "smileBlink", {"mouthSmile_L": 1.0, "eyeBlink_L": 1.0}, 0.03, rng)
    combo = driven.add_combination(ob, ["mouthSmile_L", "eyeBlink_L"], "smileBlink")
    key = ob.data.shape_keys
    for fc in key.animation_data.drivers:
        assert fc.driver.is_simple_expression, fc.driver.expression  # no Python at playback
    model = shapekeys.read_blendshape_model(ob)
    assert model.n_targets == 52 and len(model.inbetweens) == 2 and len(model.combinations) == 1
    assert ib not in shapekeys.slider_names(ob) and combo not in shapekeys.slider_names(ob)
    # the sculpt is reproduced exactly at the combination's corner
    w = np.zeros(52)
    w[[model.index("mouthSmile_L"), model.index("eyeBlink_L")]] = 1.0
    shapekeys.write_slider_values(ob, model.names, w)
    assert rel_error(evaluated(ob), sculpt) < 1e-6
    # random settings, with jawOpen sweeping through the knots
    for j in np.linspace(0, 1, 9):
        w = rng.uniform(0, 1, 52)
        w[model.index("jawOpen")] = j
        shapekeys.write_slider_values(ob, model.names, w)
        assert rel_error(model.evaluate(w), evaluated(ob)) < 1e-5


def test_drag_solve_on_a_rig_with_driven_keys_reaches_blender_positions(registered):
    ob = _facecap()
    rng = np.random.default_rng(1)
    _sculpt(ob, "jawHalf", {"jawOpen": 0.5}, 0.03, rng)
    driven.add_inbetween(ob, "jawOpen", "jawHalf", 0.5)
    model = shapekeys.read_blendshape_model(ob)
    w_true = np.zeros(model.n_targets)
    w_true[model.index("jawOpen")] = 0.35
    pins = [Pin.at_vertex(i) for i in rng.choice(model.n_vertices, 12, replace=False)]
    targets = pin_positions(model, pins, w_true)
    res = solve_drag(model, pins, targets, np.zeros(model.n_targets), alpha=1e-4, mu=1e-6)
    shapekeys.write_slider_values(ob, model.names, res.weights)
    got = evaluated(ob)
    idx = [p.vertices[0] for p in pins]
    assert np.abs(got[idx] - targets).max() < 0.02 * model.scale
    assert abs(res.weights[model.index("jawOpen")] - 0.35) < 0.05


def test_driven_key_bad_input_leaves_file_unchanged():
    ob = _facecap()
    before = blend_fingerprint()
    with pytest.raises(ShapeSpaceError, match="strictly between 0 and 1"):
        driven.add_inbetween(ob, "jawOpen", "mouthClose", 1.0)
    with pytest.raises(ShapeSpaceError, match="no shape key named"):
        driven.add_inbetween(ob, "jawOpen", "nope", 0.5)
    with pytest.raises(ShapeSpaceError, match="2 or 3 different"):
        driven.add_combination(ob, ["jawOpen"], "mouthClose")
    assert blend_fingerprint() == before


def test_inbetween_and_combination_operators(registered):
    ob = _facecap()
    bpy.context.view_layer.objects.active = ob
    rng = np.random.default_rng(4)
    _sculpt(ob, "jawHalf", {"jawOpen": 0.5}, 0.02, rng)
    ob.active_shape_key_index = ob.data.shape_keys.key_blocks.find("jawHalf")
    assert bpy.ops.shapespace.add_inbetween(primary="jawOpen", weight=0.5) == {"FINISHED"}
    assert "jawHalf" not in ob.data.shape_keys.key_blocks
    sculpt = _sculpt(ob, "browCombo", {"browInnerUp": 1.0, "browOuterUp_L": 1.0}, 0.02, rng)
    ob.active_shape_key_index = ob.data.shape_keys.key_blocks.find("browCombo")
    assert bpy.ops.shapespace.add_combination(first="browInnerUp", second="browOuterUp_L") == {"FINISHED"}
    model = shapekeys.read_blendshape_model(ob)
    assert len(model.inbetweens) == 1 and len(model.combinations) == 1
    w = np.zeros(model.n_targets)
    w[[model.index("browInnerUp"), model.index("browOuterUp_L")]] = 1.0
    shapekeys.write_slider_values(ob, model.names, w)
    assert rel_error(evaluated(ob), sculpt) < 1e-6
    # bad input: the operator cancels with the reason and changes nothing
    _sculpt(ob, "other", {"jawOpen": 0.2}, 0.01, rng)
    ob.active_shape_key_index = ob.data.shape_keys.key_blocks.find("other")
    before = blend_fingerprint()
    with pytest.raises(RuntimeError, match="no shape key named 'nope'"):
        bpy.ops.shapespace.add_inbetween(primary="nope", weight=0.3)
    with pytest.raises(RuntimeError, match="already has an in-between at 0.5"):
        bpy.ops.shapespace.add_inbetween(primary="jawOpen", weight=0.5)
    assert blend_fingerprint() == before
    ob.active_shape_key_index = 0
    assert not bpy.ops.shapespace.add_inbetween.poll()


@pytest.mark.parametrize("value", [np.nan, np.inf])
@pytest.mark.parametrize("op_name, kwargs", [("add_combination", {"first": "K0", "second": "K1"}),
                                             ("add_inbetween", {"primary": "K0", "weight": 0.5})])
def test_nan_in_an_input_key_is_refused_by_name(registered, op_name, kwargs, value):
    """#26.6: a NaN coordinate in an input key is refused naming the key and the vertex; nothing changes (before:
    FINISHED, the NaN copied into the new key)."""
    from blender_support import sphere_rig
    ob = sphere_rig(3)
    kb = ob.data.shape_keys.key_blocks["K0"]
    co = np.empty(len(kb.data) * 3, np.float32)
    kb.data.foreach_get("co", co)
    co[3 * 7 + 2] = value
    kb.data.foreach_set("co", co)
    bpy.context.view_layer.objects.active = ob
    ob.active_shape_key_index = 3                       # K2: the sculpt
    before = blend_fingerprint()
    with pytest.raises(RuntimeError, match=rf"shape key 'K0' of 'Face' has a non-finite coordinate \(z = {value}\) "
                                           r"at vertex 7"):
        getattr(bpy.ops.shapespace, op_name)("EXEC_DEFAULT", **kwargs)
    assert blend_fingerprint() == before
    assert [k.name for k in ob.data.shape_keys.key_blocks] == ["Basis", "K0", "K1", "K2"]
