"""Issue #10 hardening of pin and drag in real Blender: NaN never reaches a slider (r08), keys that move nothing
keep their sliders, world-space targets, iteration limits reported, stale pins refused in one line."""
import os
import re

import numpy as np
import pytest

from support import ASSETS, shared
from blender_support import blend_fingerprint, bpy, classify_operator_call, evaluated, import_file, sphere_rig
from shapespace.bridge import actions, manipulation, meshes, shapekeys, skin
from shapespace.bridge.manipulation import drag
from shapespace.core.manipulation import DragResult, DragSession, Pin, pin_positions
from shapespace.core.result import ShapeSpaceError, Status

FACECAP = os.path.join(ASSETS, "facecap", "facecap_decoded.glb")


def _sphere(keys=4, name="Face"):
    ob = sphere_rig(keys, name)
    for k in range(keys):
        kb = ob.data.shape_keys.key_blocks[f"K{k}"]
        kb.value = 0.0
    ob.shapespace.mode = "DIRECT"
    bpy.context.view_layer.objects.active = ob
    return ob


def _set_co(kb, vertex, axis, value):
    co = np.empty(len(kb.data) * 3, np.float32)
    kb.data.foreach_get("co", co)
    co[3 * vertex + axis] = value
    kb.data.foreach_set("co", co)


def _sliders(ob):
    return [kb.value for kb in ob.data.shape_keys.key_blocks[1:]]


def _reports(text):
    return re.findall(r"^(Info|Warning|Error): (.*)$", text, re.MULTILINE)


def _facecap(keep_anim=False):
    import_file(FACECAP)
    ob = bpy.data.objects["Mesh_2"]
    if not keep_anim:
        ob.data.shape_keys.animation_data.action = None
        names = shapekeys.slider_names(ob)
        shapekeys.write_slider_values(ob, names, np.zeros(len(names)))
    bpy.context.view_layer.objects.active = ob
    return ob


# =========================================================================== r08: NaN never written
def test_r08_nan_coordinate_at_a_pinned_vertex_is_refused_and_nothing_changes(registered):
    ob = _sphere()
    assert bpy.ops.shapespace.add_pin(vertices=(5, 0, 0)) == {"FINISHED"}
    _set_co(ob.data.shape_keys.key_blocks["K1"], 5, 1, np.nan)
    before, target_before = blend_fingerprint(), tuple(ob.shapespace.pins[0].target)
    with pytest.raises(RuntimeError, match=r"'K1'.*vertex 5"):
        bpy.ops.shapespace.solve_pins(pin=0, target=(0.1, 0.2, 0.3), key=True)
    assert blend_fingerprint() == before
    assert tuple(ob.shapespace.pins[0].target) == target_before
    assert ob.data.shape_keys.animation_data is None or ob.data.shape_keys.animation_data.action is None
    assert np.isfinite(_sliders(ob)).all()
    with pytest.raises(RuntimeError, match=r"'K1'.*vertex 5"):
        bpy.ops.shapespace.add_pin(vertices=(5, 0, 0))
    assert len(ob.shapespace.pins) == 1


def test_r08_nan_slider_min_is_refused_naming_the_key(registered):
    ob = _sphere()
    bpy.ops.shapespace.add_pin(vertices=(3, 0, 0))
    ob.data.shape_keys.key_blocks["K1"].slider_min = float("nan")
    before = blend_fingerprint()
    with pytest.raises(RuntimeError, match=r"'K1'.*slider_min"):
        bpy.ops.shapespace.solve_pins(pin=0, target=(0.1, 0.2, 0.3))
    assert blend_fingerprint() == before
    assert np.isfinite(_sliders(ob)).all()


def test_non_finite_target_argument_leaves_the_pin_alone(registered):
    ob = _sphere()
    bpy.ops.shapespace.add_pin(vertices=(3, 0, 0))
    target_before = tuple(ob.shapespace.pins[0].target)
    with pytest.raises(RuntimeError, match="not finite"):
        bpy.ops.shapespace.solve_pins(pin=0, target=(float("nan"), 0.0, 0.0))
    assert tuple(ob.shapespace.pins[0].target) == target_before      # was overwritten with NaN before
    ob.shapespace.pins[0].target = (0.0, float("nan"), 0.0)          # a damaged stored target
    before = blend_fingerprint()
    with pytest.raises(RuntimeError, match="target of pin 0 is not finite"):
        bpy.ops.shapespace.solve_pins()
    assert blend_fingerprint() == before


def test_cached_nan_models_are_refused_in_the_drag_and_add_pin_paths(registered):
    """A model read once (a drag reads it when it starts) is checked by the solve itself, not only on read."""
    ob = _sphere()
    manipulation.add_pin(ob, Pin.at_vertex(7))
    _set_co(ob.data.shape_keys.key_blocks["K2"], 40, 0, np.inf)
    model = shapekeys.read_blendshape_model(ob, finite=False)      # a stale cached read
    before, n_pins = blend_fingerprint(), len(ob.shapespace.pins)
    with pytest.raises(ShapeSpaceError, match=r"'K2'.*vertex 40"):
        manipulation.solve_pins(ob, model=model, session=DragSession())
    depsgraph = bpy.context.evaluated_depsgraph_get()
    world = meshes.to_world(ob, model.neutral[7][None])[0] + 0.05
    with pytest.raises(ShapeSpaceError, match=r"'K2'.*vertex 40"):
        manipulation.drag_step(ob, depsgraph, 0, world, model, None, model.values, model.values, DragSession())
    with pytest.raises(ShapeSpaceError, match=r"'K2'.*vertex 40"):
        manipulation.add_pin(ob, Pin.at_vertex(40), None, model=model)
    assert blend_fingerprint() == before and len(ob.shapespace.pins) == n_pins
    assert tuple(ob.shapespace.pins[0].target) == pytest.approx(tuple(model.neutral[7]))


def test_the_slider_write_refuses_a_non_finite_value(registered, monkeypatch):
    """The last guard: whatever a solver returns, no NaN/inf is written into a slider."""
    ob = _sphere()
    manipulation.add_pin(ob, Pin.at_vertex(3))

    def nan_solver(model, pins, targets, *args, **kwargs):
        w = np.zeros(model.n_targets)
        w[2] = np.nan
        return DragResult(w, objective=0.0, residuals=np.zeros(len(pins)))

    monkeypatch.setattr(drag, "solve_drag", nan_solver)
    before = blend_fingerprint()
    with pytest.raises(RuntimeError, match=r"refusing to write nan into shape key 'K2'"):
        bpy.ops.shapespace.solve_pins(pin=0, target=(0.0, 0.0, 1.0), key=True)
    assert blend_fingerprint() == before


def test_add_pin_refuses_bad_pins_before_storing_anything(registered):
    ob = _sphere()
    with pytest.raises(RuntimeError, match="barycentric"):
        bpy.ops.shapespace.add_pin(vertices=(3, 4, 0), weights=(0.2, 0.2, 0.0), use_target=True,
                                   target=(0.0, 0.0, 1.0))
    assert len(ob.shapespace.pins) == 0


# =========================================================================== keys that move nothing
@pytest.mark.parametrize("mode", ["DIRECT", "LEARNED"])
def test_facecap_empty_key_keeps_its_slider_and_is_not_keyed(registered, mode):
    ob = _facecap(keep_anim=True)
    action = actions.active_action(ob.data.shape_keys)
    ob.data.shape_keys.animation_data.action = None
    names = shapekeys.slider_names(ob)
    shapekeys.write_slider_values(ob, names, np.zeros(len(names)))
    model = shapekeys.read_blendshape_model(ob)
    empty = model.index("tongueOut")
    assert np.abs(model.deltas[empty]).max() == 0.0                 # the asset's tongueOut moves nothing
    st = ob.shapespace
    st.mode = mode
    if mode == "LEARNED":
        st.prior_action, st.prior_start, st.prior_end = action, 2, 160
    v = int(np.argmax(np.linalg.norm(model.deltas[model.index("jawOpen")], axis=1)))
    bpy.ops.shapespace.add_pin(vertices=(v, 0, 0))
    target = model.neutral[v] + 0.7 * model.deltas[model.index("jawOpen"), v]
    bpy.context.scene.frame_set(5)
    assert bpy.ops.shapespace.solve_pins(pin=0, target=target, key=True) == {"FINISHED"}
    w = shapekeys.read_slider_values(ob, model.names)
    assert w[empty] == 0.0, w[empty]                              # Learned mode used to set 0.46
    assert w[model.index("jawOpen")] > 0.1
    keyed = set(actions.shape_key_curves(ob))
    assert keyed and "tongueOut" not in keyed
    # from a non-zero start too (μ used to pull it toward 0)
    shapekeys.write_slider_values(ob, ["tongueOut"], [0.4])
    assert bpy.ops.shapespace.solve_pins(pin=0, target=target) == {"FINISHED"}
    assert shapekeys.read_slider_values(ob, ["tongueOut"])[0] == np.float32(0.4)     # bit for bit


# =========================================================================== space of a scripted target
def _transformed_sphere():
    parent = bpy.data.objects.new("Rig", None)
    bpy.context.scene.collection.objects.link(parent)
    parent.location, parent.rotation_euler, parent.scale = (1.0, -2.0, 0.5), (0.4, -0.3, 1.1), (2.0, 2.0, 2.0)
    ob = _sphere()
    ob.parent = parent
    ob.location, ob.rotation_euler, ob.scale = (0.3, 0.2, -0.7), (-0.5, 0.8, 0.2), (1.0, 1.5, 0.7)
    bpy.context.view_layer.update()
    return ob


def _goal(ob, v):
    model = shapekeys.read_blendshape_model(ob)
    w = np.array([0.6, 0.2, 0.0, 0.4])
    return model, pin_positions(model, [Pin.at_vertex(v)], w)[0]


def test_world_space_target_equals_the_local_one_under_parent_and_transforms(registered):
    ob = _transformed_sphere()
    v = 20
    model, local = _goal(ob, v)
    world = meshes.to_world(ob, local[None])[0]
    assert np.linalg.norm(world - local) > 1.0                     # the spaces really differ
    assert bpy.ops.shapespace.add_pin(vertices=(v, 0, 0)) == {"FINISHED"}
    start = tuple(ob.shapespace.pins[0].target)

    assert bpy.ops.shapespace.solve_pins(pin=0, target=local, space="LOCAL") == {"FINISHED"}
    w_local, at_local = shapekeys.read_slider_values(ob, model.names), evaluated(ob)
    shapekeys.write_slider_values(ob, model.names, np.zeros(model.n_targets))
    ob.shapespace.pins[0].target = start
    assert bpy.ops.shapespace.solve_pins(pin=0, target=world, space="WORLD") == {"FINISHED"}
    np.testing.assert_allclose(shapekeys.read_slider_values(ob, model.names), w_local, atol=1e-6)
    np.testing.assert_allclose(evaluated(ob), at_local, atol=1e-6)
    np.testing.assert_allclose(ob.shapespace.pins[0].target, local, atol=1e-5)
    # the pin, as Blender evaluates it in world space, went toward the world target
    got = meshes.to_world(ob, evaluated(ob)[v][None])[0]
    rest = meshes.to_world(ob, model.neutral[v][None])[0]
    assert np.linalg.norm(got - world) < 0.5 * np.linalg.norm(rest - world)

    # add_pin takes a world-space target the same way
    assert bpy.ops.shapespace.add_pin(vertices=(v + 1, 0, 0), use_target=True, target=world,
                                      space="WORLD") == {"FINISHED"}
    np.testing.assert_allclose(ob.shapespace.pins[1].target, local, atol=1e-5)


def test_readme_scripting_snippet_moves_a_pin_to_the_cursor(registered):
    """The README's "Pin and drag" snippet, run as written (add_pin, then solve_pins to the 3D cursor)."""
    readme = open(os.path.join(os.path.dirname(ASSETS), "README.md"), encoding="utf-8").read()
    section = readme[readme.index("## Pin and drag"):]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    code = "\n".join(line.strip() for line in code.splitlines())
    assert "add_pin" in code and "space='WORLD'" in code
    ob = _transformed_sphere()
    v = 20
    model, local = _goal(ob, v)
    bpy.context.scene.cursor.location = meshes.to_world(ob, local[None])[0]
    exec(code, {"bpy": bpy, "v": v})
    np.testing.assert_allclose(ob.shapespace.pins[0].target, local, atol=1e-5)
    got = meshes.to_world(ob, evaluated(ob)[v][None])[0]
    rest = meshes.to_world(ob, model.neutral[v][None])[0]
    cursor = np.array(bpy.context.scene.cursor.location)
    assert np.linalg.norm(got - cursor) < 0.5 * np.linalg.norm(rest - cursor)


def test_a_world_point_passed_as_local_is_flagged(registered, capfd):
    ob = _transformed_sphere()
    model, local = _goal(ob, 20)
    world = meshes.to_world(ob, local[None])[0]
    bpy.ops.shapespace.add_pin(vertices=(20, 0, 0))
    capfd.readouterr()
    assert bpy.ops.shapespace.solve_pins(pin=0, target=world) == {"FINISHED"}   # default: LOCAL
    reports = _reports(capfd.readouterr().out + capfd.readouterr().err)
    assert any(level == "Warning" and "space='WORLD'" in text for level, text in reports), reports


def test_world_target_on_a_zero_scale_object_is_refused(registered):
    ob = _sphere()
    bpy.ops.shapespace.add_pin(vertices=(3, 0, 0))
    ob.scale = (1.0, 0.0, 1.0)
    bpy.context.view_layer.update()
    before = blend_fingerprint()
    with pytest.raises(RuntimeError, match="cannot be inverted"):
        bpy.ops.shapespace.solve_pins(pin=0, target=(0.0, 0.0, 1.0), space="WORLD")
    assert blend_fingerprint() == before


def test_world_target_on_a_skinned_posed_head(registered):
    """WORLD means where the point appears: through the posed armature (as a viewport drag)."""
    import_file(shared("rpm_brunette", "brunette-t.glb"))
    ob = bpy.data.objects["Wolf3D_Head"]
    bpy.context.view_layer.objects.active = ob
    arm = skin.armature_modifiers(ob)[0].object
    arm.scale = (1.0, 1.3, 0.8)
    bone = arm.pose.bones["Head"]
    bone.rotation_mode = "XYZ"
    bone.rotation_euler = (0.3, 0.2, -0.25)
    bpy.context.view_layer.update()
    model = shapekeys.read_blendshape_model(ob)
    v = int(np.argmax(np.linalg.norm(model.deltas[model.index("jawOpen")], axis=1)))
    shapekeys.write_slider_values(ob, ["jawOpen"], [0.5])
    goal_world = meshes.to_world(ob, evaluated(ob)[v][None])[0]
    shapekeys.write_slider_values(ob, ["jawOpen"], [0.0])
    ob.shapespace.mode = "DIRECT"
    ob.shapespace.alpha, ob.shapespace.mu = 1e-5, 1e-7
    assert bpy.ops.shapespace.add_pin(vertices=(v, 0, 0)) == {"FINISHED"}
    assert bpy.ops.shapespace.solve_pins(pin=0, target=goal_world, space="WORLD") == {"FINISHED"}
    got_world = meshes.to_world(ob, evaluated(ob)[v][None])[0]
    size = np.ptp(meshes.to_world(ob, evaluated(ob)), axis=0).max()
    assert np.linalg.norm(got_world - goal_world) < 1e-3 * size


# =========================================================================== iteration limit
def _inbetween_sphere():
    ob = _sphere()
    blocks = ob.data.shape_keys.key_blocks
    base = np.empty(len(ob.data.vertices) * 3, np.float32)
    blocks["Basis"].data.foreach_get("co", base)
    k0 = np.empty_like(base)
    blocks["K0"].data.foreach_get("co", k0)
    rng = np.random.default_rng(4)
    mid = ob.shape_key_add(name="K0_half")
    mid.data.foreach_set("co", (base + 0.5 * (k0 - base) + rng.normal(0, 0.08, base.size)).astype(np.float32))
    ob.active_shape_key_index = len(blocks) - 1
    assert bpy.ops.shapespace.add_inbetween(primary="K0", weight=0.5) == {"FINISHED"}
    return ob


def test_solve_pins_at_the_iteration_limit_warns_not_converged(registered, monkeypatch, capfd):
    ob = _inbetween_sphere()
    model = shapekeys.read_blendshape_model(ob)
    assert not model.is_linear
    for v in (3, 17, 30, 44):
        manipulation.add_pin(ob, Pin.at_vertex(v), pin_positions(model, [Pin.at_vertex(v)],
                                                                 np.array([0.35, 0.8, 0.1, 0.6]))[0])
    ob.shapespace.alpha, ob.shapespace.mu = 1e-4, 1e-6
    full = manipulation.solve_pins(ob, w0=np.zeros(model.n_targets))
    assert full.status != Status.NOT_CONVERGED
    shapekeys.write_slider_values(ob, model.names, np.zeros(model.n_targets))
    real = drag.solve_drag
    monkeypatch.setattr(drag, "solve_drag", lambda *a, **k: real(*a, **k, gn_max_iter=1))
    capfd.readouterr()
    assert bpy.ops.shapespace.solve_pins() == {"FINISHED"}
    reports = _reports(capfd.readouterr().out)
    assert reports and reports[-1][0] == "Warning" and reports[-1][1].startswith("not converged"), reports
    result = manipulation.solve_pins(ob)
    assert result.status == Status.NOT_CONVERGED
    assert "NOT CONVERGED" in manipulation.drag_status_line(result)
    assert "NOT CONVERGED" not in manipulation.drag_status_line(full)


# =========================================================================== stale pins (r18-like)
def _delete_last_vertices(ob, count):
    import bmesh

    bm = bmesh.new()
    bm.from_mesh(ob.data)
    bm.verts.ensure_lookup_table()
    bmesh.ops.delete(bm, geom=list(bm.verts)[-count:], context="VERTS")
    bm.to_mesh(ob.data)
    bm.free()
    ob.data.update()


def test_pins_after_a_topology_change_are_refused_in_one_line(registered):
    ob = _sphere()
    last = len(ob.data.vertices) - 1
    bpy.ops.shapespace.add_pin(vertices=(last, 0, 0))
    _delete_last_vertices(ob, 5)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    for call in (lambda: manipulation.deformed_pin_positions(ob, depsgraph),
                 lambda: manipulation.drag_step(ob, depsgraph, 0, (0.0, 0.0, 1.0), shapekeys.read_blendshape_model(ob),
                                                None, np.zeros(4), np.zeros(4), DragSession())):
        with pytest.raises(ShapeSpaceError, match="clear the pins"):
            call()
    for op, kwargs in (("solve_pins", {}), ("solve_pins", {"pin": 0, "target": (0, 0, 1), "space": "WORLD"}),
                       ("add_pin", {"vertices": (1, 0, 0)}), ("remove_pin", {"index": 0}), ("clear_pins", {})):
        outcome, message = classify_operator_call(op, kwargs)
        assert outcome in ("refused", "cancelled", "finished"), (op, outcome, message)
    from shapespace.ui import overlay
    assert overlay.draw_pins(ob, depsgraph) == 0


def test_pins_on_a_mesh_whose_shape_keys_were_deleted(registered):
    ob = _sphere()
    bpy.ops.shapespace.add_pin(vertices=(3, 0, 0))
    ob.shape_key_clear()
    for op, kwargs in (("solve_pins", {"pin": 0, "target": (0, 0, 1)}), ("add_pin", {"vertices": (1, 0, 0)}),
                       ("remove_pin", {"index": 0})):
        outcome, message = classify_operator_call(op, kwargs)
        assert outcome in ("refused", "cancelled", "finished"), (op, outcome, message)
    from shapespace.ui import overlay
    assert overlay.draw_pins(ob, bpy.context.evaluated_depsgraph_get()) == 0


def test_world_target_with_a_topology_changing_modifier_is_refused(registered):
    ob = _sphere()
    bpy.ops.shapespace.add_pin(vertices=(3, 0, 0))
    ob.modifiers.new("Sub", "SUBSURF")
    before = blend_fingerprint()
    with pytest.raises(RuntimeError, match="deform-only modifiers"):
        bpy.ops.shapespace.solve_pins(pin=0, target=(0.0, 0.0, 1.0), space="WORLD")
    assert blend_fingerprint() == before
