"""Pins, the scriptable drag solve, learned mode, skinned rigs and the overlay, in real Blender."""
import os

import numpy as np
import pytest

from support import ASSETS, shared
from blender_support import blend_fingerprint, bpy, evaluated, import_file, rel_error
from shapespace.bridge import actions, manipulation, meshes, shapekeys, skin
from shapespace.core.manipulation import Pin, pin_positions, solve_drag_reference

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
