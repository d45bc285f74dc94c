"""Pins, the scriptable drag solve, learned mode, skinned rigs and the overlay, in real Blender; hardening
(issue #10): NaN never reaches a slider, keys that move nothing keep their sliders, world-space targets,
iteration limits reported, stale pins refused in one line."""
import os
import re

import numpy as np
import pytest

from blender_support import (
    blend_fingerprint,
    bpy,
    classify_operator_call,
    evaluated,
    import_file,
    rel_error,
    sphere_rig,
)
from shapespace.bridge import actions, manipulation, meshes, shapekeys, skin
from shapespace.bridge.manipulation import drag
from shapespace.core.manipulation import DragResult, DragSession, Pin, pin_positions, solve_drag_reference
from shapespace.core.result import ShapeSpaceError, Status
from support import ASSETS, shared

FACECAP = os.path.join(ASSETS, "facecap", "facecap_decoded.glb")


def _facecap(keep_anim=False):
    import_file(FACECAP)
    ob = bpy.data.objects["Mesh_2"]
    if not keep_anim:
        ob.data.shape_keys.animation_data.action = None
        names = shapekeys.slider_names(ob)
        shapekeys.write_slider_values(ob, names, np.zeros(len(names)))
    bpy.context.view_layer.objects.active = ob
    return ob


def _jaw_vertex(model):
    return int(np.argmax(np.linalg.norm(model.deltas[model.index("jawOpen")], axis=1)))


def test_solve_operator_drags_the_face_like_the_reference_solver(registered):
    ob = _facecap()
    model = shapekeys.read_blendshape_model(ob)
    v = _jaw_vertex(model)
    w_goal = np.zeros(model.n_targets)
    w_goal[model.index("jawOpen")] = 0.6
    target = pin_positions(model, [Pin.at_vertex(v)], w_goal)[0]
    assert bpy.ops.shapespace.add_pin(vertices=(v, 0, 0), weights=(1, 0, 0)) == {"FINISHED"}
    assert bpy.ops.shapespace.solve_pins(pin=0, target=target) == {"FINISHED"}
    got = shapekeys.read_slider_values(ob, model.names)
    ref = solve_drag_reference(model, [Pin.at_vertex(v)], target[None], np.zeros(model.n_targets))
    np.testing.assert_allclose(got, ref, atol=2e-6)  # sliders are stored as float32
    # Blender's own evaluation puts the pinned vertex near the target (α pulls it back slightly)
    moved = evaluated(ob)[v]
    start = model.neutral[v]
    assert np.linalg.norm(moved - target) < 0.5 * np.linalg.norm(target - start)


def test_surface_pin_from_a_ray_lies_on_blenders_surface(registered):
    ob = _facecap()
    model = shapekeys.read_blendshape_model(ob)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    world = meshes.to_world(ob, evaluated(ob))
    centre = world.mean(axis=0)
    origin = centre + np.array([0.0, -1.0, 0.0]) * np.ptp(world, axis=0).max() * 3
    hit = manipulation.surface_pin(ob, depsgraph, origin, centre - origin)
    assert hit is not None
    pin, hit_world = hit
    assert len(pin.vertices) == 3 and abs(sum(pin.weights) - 1) < 1e-9
    on_surface = meshes.to_world(ob, pin_positions(model, [pin], model.values))[0]
    assert np.linalg.norm(on_surface - hit_world) < 1e-5 * np.ptp(world, axis=0).max()
    miss = manipulation.surface_pin(ob, depsgraph, origin, origin - centre)
    assert miss is None


def test_pins_persist_through_save_and_reload(registered, tmp_path):
    _facecap()
    bpy.ops.shapespace.add_pin(vertices=(10, 11, 12), weights=(0.2, 0.3, 0.5), stationary=True)
    path = str(tmp_path / "pins.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.open_mainfile(filepath=path)
    pins, targets, still = manipulation.read_pins(bpy.data.objects["Mesh_2"])
    assert pins == [Pin((10, 11, 12), (pytest.approx(0.2), pytest.approx(0.3), pytest.approx(0.5)))] or (
        pins[0].vertices == (10, 11, 12) and np.allclose(pins[0].weights, (0.2, 0.3, 0.5)))
    assert still.tolist() == [True] and np.isfinite(targets).all()


def test_learned_mode_trains_on_the_capture(registered):
    ob = _facecap(keep_anim=True)
    action = actions.active_action(ob.data.shape_keys)
    ob.data.shape_keys.animation_data.action = None
    model = shapekeys.read_blendshape_model(ob)
    st = ob.shapespace
    st.mode, st.prior_action, st.prior_start, st.prior_end = "LEARNED", action, 2, 160
    v = _jaw_vertex(model)
    bpy.ops.shapespace.add_pin(vertices=(v, 0, 0))
    target = model.neutral[v] + 0.5 * model.deltas[model.index("jawOpen"), v]
    assert bpy.ops.shapespace.solve_pins(pin=0, target=target) == {"FINISHED"}
    w = shapekeys.read_slider_values(ob, model.names)
    assert w[model.index("jawOpen")] > 0.1
    st.snap = True
    assert bpy.ops.shapespace.solve_pins() == {"FINISHED"}


@pytest.mark.parametrize("case", ["other_id", "one_frame", "no_action"])
def test_learned_mode_bad_priors_cancel_cleanly(registered, case):
    ob = _facecap(keep_anim=True)
    st = ob.shapespace
    st.mode = "LEARNED"
    bpy.ops.shapespace.add_pin(vertices=(5, 0, 0))
    key_action = actions.active_action(ob.data.shape_keys)
    if case == "other_id":
        st.prior_action = next(a for a in bpy.data.actions if a != key_action)
        expected = "animates none"
    elif case == "one_frame":
        st.prior_action, st.prior_start, st.prior_end = key_action, 50, 50
        expected = "at least 2 frames"
    else:
        expected = "needs a prior action"
    before = blend_fingerprint()
    with pytest.raises(RuntimeError, match=expected):
        bpy.ops.shapespace.solve_pins()
    assert blend_fingerprint() == before


def test_deleting_a_shape_key_and_editing_topology(registered):
    ob = _facecap()
    bpy.ops.shapespace.add_pin(vertices=(100, 0, 0))
    ob.shape_key_remove(ob.data.shape_keys.key_blocks["mouthRollLower"])
    assert bpy.ops.shapespace.solve_pins() == {"FINISHED"}
    ob.shapespace.pins[0].vertices = (len(ob.data.vertices) + 5, 0, 0)
    before = blend_fingerprint()
    with pytest.raises(RuntimeError, match="clear the pins"):
        bpy.ops.shapespace.solve_pins()
    assert blend_fingerprint() == before


def test_sliders_mode_disables_dragging(registered):
    ob = _facecap()
    ob.shapespace.mode = "SLIDERS"
    bpy.ops.shapespace.add_pin(vertices=(1, 0, 0))
    assert not bpy.ops.shapespace.solve_pins.poll()


def test_drag_on_a_skinned_posed_head_with_scaled_parent(registered):
    """A drag given in world space on a posed, armature-deformed head with a non-uniformly scaled parent."""
    import_file(shared("rpm_brunette", "brunette-t.glb"))
    ob = bpy.data.objects["Wolf3D_Head"]
    bpy.context.view_layer.objects.active = ob
    arm = skin.armature_modifiers(ob)[0].object
    arm.scale = (1.0, 1.3, 0.8)
    head_bone = arm.pose.bones["Head"]
    head_bone.rotation_mode = "XYZ"
    head_bone.rotation_euler = (0.3, 0.2, -0.25)
    bpy.context.view_layer.update()
    depsgraph = bpy.context.evaluated_depsgraph_get()
    model = shapekeys.read_blendshape_model(ob)
    v = int(np.argmax(np.linalg.norm(model.deltas[model.index("jawOpen")], axis=1)))
    pin = Pin.at_vertex(v)
    # where jawOpen = 0.5 would put this vertex, in world space, as Blender evaluates it
    shapekeys.write_slider_values(ob, ["jawOpen"], [0.5])
    goal_world = meshes.to_world(ob, evaluated(ob)[v][None])[0]
    shapekeys.write_slider_values(ob, ["jawOpen"], [0.0])
    manipulation.add_pin(ob, pin, pin_positions(model, [pin], np.zeros(model.n_targets))[0])
    model = shapekeys.read_blendshape_model(ob)
    local = meshes.to_local(ob, goal_world[None])[0]
    target = manipulation.deformed_to_shape_space(ob, depsgraph, pin, model, model.values, local)
    ob.shapespace.pins[0].target = target
    ob.shapespace.alpha, ob.shapespace.mu = 1e-5, 1e-7
    result = manipulation.solve_pins(ob)
    assert result.residuals.max() < 1e-4 * model.scale, result.message
    got_world = meshes.to_world(ob, evaluated(ob)[v][None])[0]
    size = np.ptp(meshes.to_world(ob, evaluated(ob)), axis=0).max()
    assert np.linalg.norm(got_world - goal_world) < 1e-3 * size


def test_auto_key_keys_only_changed_sliders(registered):
    ob = _facecap()
    before = manipulation.current_sliders(ob)
    after = before[1].copy()
    after[[3, 7]] = 0.4
    shapekeys.write_slider_values(ob, before[0], after)
    assert manipulation.key_changed(ob, before, after, 12) == 2
    assert set(actions.shape_key_curves(ob)) == {before[0][3], before[0][7]}


def _init_gpu():
    """The bpy module runs in background mode, where Python's gpu module stays locked until a
    GPU context exists; a tiny Workbench render creates one (EGL, no display needed)."""
    scene = bpy.context.scene
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.render.resolution_x = scene.render.resolution_y = 8
    cam = bpy.data.objects.new("GpuInitCam", bpy.data.cameras.new("GpuInitCam"))
    scene.collection.objects.link(cam)
    scene.camera = cam
    bpy.ops.render.render()
    bpy.data.objects.remove(cam)


def test_overlay_draws_pins_offscreen(registered):
    import gpu
    from mathutils import Matrix

    from shapespace.ui import overlay

    _init_gpu()
    ob = _facecap()
    model = shapekeys.read_blendshape_model(ob)
    v = _jaw_vertex(model)
    manipulation.add_pin(ob, Pin.at_vertex(v), model.neutral[v] + model.deltas[model.index("jawOpen"), v])
    manipulation.add_pin(ob, Pin.at_vertex(0), model.neutral[0], stationary=True)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    current, goal, still = overlay.pin_world_points(ob, depsgraph)
    pts = np.concatenate([current, goal])
    lo, hi = pts.min(0), pts.max(0)
    centre, half = (lo + hi) / 2, float((hi - lo).max()) * 0.75 + 1e-6
    # orthographic camera looking along +Y at the pins
    view = Matrix(((1, 0, 0, -centre[0]), (0, 0, 1, -centre[2]), (0, -1, 0, centre[1] - 10 * half),
                   (0, 0, 0, 1)))
    proj = Matrix(((1 / half, 0, 0, 0), (0, 1 / half, 0, 0), (0, 0, -1 / (20 * half), 0), (0, 0, 0, 1)))
    size = 128
    off = gpu.types.GPUOffScreen(size, size)
    with off.bind():
        fb = gpu.state.active_framebuffer_get()
        fb.clear(color=(0.0, 0.0, 0.0, 0.0))
        with gpu.matrix.push_pop():
            gpu.matrix.load_matrix(view)
            with gpu.matrix.push_pop_projection():
                gpu.matrix.load_projection_matrix(proj)
                drawn = overlay.draw_pins(ob, depsgraph)
        pixels = np.array(fb.read_color(0, 0, size, size, 4, 0, "FLOAT").to_list()).reshape(size, size, 4)
    off.free()
    assert drawn == 2
    view_np, proj_np = np.array(view), np.array(proj)

    def pixel_of(p):
        clip = proj_np @ view_np @ np.append(p, 1.0)
        ndc = clip[:3] / clip[3]
        return int((ndc[1] * 0.5 + 0.5) * size), int((ndc[0] * 0.5 + 0.5) * size)

    def colour_near(p, rgb):
        r, c = pixel_of(p)
        patch = pixels[max(r - 3, 0):r + 4, max(c - 3, 0):c + 4, :3]
        return np.any(np.all(np.abs(patch - rgb) < 0.05, axis=-1))

    assert colour_near(current[0], overlay.PIN_COLOR[:3])
    assert colour_near(current[1], overlay.STILL_COLOR[:3])
    assert colour_near(goal[0], overlay.TARGET_COLOR[:3])


def test_muted_masked_and_extended_range_keys_in_a_drag(registered):
    ob = _facecap()
    blocks = ob.data.shape_keys.key_blocks
    group = ob.vertex_groups.new(name="lower")
    co = np.empty(len(ob.data.vertices) * 3, np.float32)
    ob.data.vertices.foreach_get("co", co)
    z = co.reshape(-1, 3)[:, 2]
    group.add(np.flatnonzero(z < np.median(z)).tolist(), 0.5, "REPLACE")
    blocks["jawOpen"].vertex_group = "lower"
    blocks["mouthSmile_L"].mute = True
    blocks["mouthSmile_L"].value = 0.3
    blocks["browInnerUp"].slider_min, blocks["browInnerUp"].slider_max = -1.0, 2.0
    model = shapekeys.read_blendshape_model(ob)
    rng = np.random.default_rng(8)
    goal_w = np.zeros(model.n_targets)
    goal_w[model.index("browInnerUp")] = 1.7
    goal_w[model.index("jawOpen")] = 0.8
    verts = rng.choice(model.n_vertices, 10, replace=False)
    for v in verts:
        bpy.ops.shapespace.add_pin(vertices=(int(v), 0, 0), use_target=True,
                                   target=tuple(pin_positions(model, [Pin.at_vertex(int(v))], goal_w)[0]))
    ob.shapespace.alpha, ob.shapespace.mu = 1e-4, 1e-6
    assert bpy.ops.shapespace.solve_pins() == {"FINISHED"}
    w = shapekeys.read_slider_values(ob, model.names)
    assert w[model.index("mouthSmile_L")] == pytest.approx(0.3)   # muted: left where it was
    assert -1.0 <= w[model.index("browInnerUp")] <= 2.0
    assert w[model.index("browInnerUp")] > 1.0                     # used the extended range
    # what Blender shows is what the solver computed (masks, mute and ranges included)
    assert rel_error(model.evaluate(w), evaluated(ob)) < 1e-5


# =========================================================================== hardening (issue #10)
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
