"""Issue #17: pin-and-drag reads the rig once — and never uses a stale cache.

The rig cache (``bridge.manipulation.RIGS``) keeps each mesh's blendshape model between mouse moves, drags
and Solve Pins calls.  Every test here changes the rig behind the cache's back the way an artist or a script
would — a key edited, added or deleted, a modifier toggled, the pose changed, undo, a rename, a second
object, a file reloaded under the same names — and checks the outcome through Blender's own evaluation or
against a solve on a freshly read rig.
"""
import numpy as np
import pytest

from blender_support import bpy, evaluated, import_file
from shapespace.bridge import manipulation, meshes, shapekeys
from shapespace.bridge.manipulation import cache
from shapespace.core.manipulation import Pin, pin_positions, solve_drag
from support import shared

RIGS = manipulation.RIGS


def _sphere(name="Face", keys=4, seed=0):
    bpy.ops.mesh.primitive_uv_sphere_add(segments=16, ring_count=8)
    ob = bpy.context.active_object
    ob.name = name
    ob.shape_key_add(name="Basis")
    base = np.empty(len(ob.data.vertices) * 3, np.float32)
    ob.data.vertices.foreach_get("co", base)
    rng = np.random.default_rng(seed)
    for k in range(keys):
        kb = ob.shape_key_add(name=f"K{k}")
        kb.data.foreach_set("co", (base + rng.normal(0, 0.08, base.size)).astype(np.float32))
        kb.value = 0.0
    ob.shapespace.mode = "DIRECT"
    ob.shapespace.alpha, ob.shapespace.mu = 1e-4, 1e-6
    bpy.context.view_layer.objects.active = ob
    bpy.context.view_layer.update()
    return ob


def _pinned_sphere(name="Face", seed=0, still=(40, 90)):
    ob = _sphere(name, seed=seed)
    manipulation.add_pin(ob, Pin.at_vertex(20))
    for v in still:
        manipulation.add_pin(ob, Pin.at_vertex(v), stationary=True)
    return ob


def _world_goal(ob, v=20, w=(0.6, 0.2, 0.0, 0.4)):
    """Where sliders ``w`` put vertex ``v``, in world space, as Blender evaluates it (sliders reset after)."""
    names = shapekeys.slider_names(ob)
    before = shapekeys.read_slider_values(ob, names)
    shapekeys.write_slider_values(ob, names, np.asarray(w, dtype=np.float64))
    goal = meshes.to_world(ob, evaluated(ob)[v][None])[0]
    shapekeys.write_slider_values(ob, names, before)
    bpy.context.view_layer.update()
    return goal


def _fresh_solution(ob, w0):
    """The sliders a solve on a freshly read rig gives for the stored pins (the unique optimum)."""
    model = shapekeys.read_blendshape_model(ob)
    pins, targets, _ = manipulation.read_pins(ob)
    st = ob.shapespace
    return model.names, solve_drag(model, pins, targets, w0, alpha=st.alpha, mu=st.mu).weights


def _sliders(ob, names=None):
    names = names or shapekeys.slider_names(ob)
    return shapekeys.read_slider_values(ob, names)


def _assert_fresh(ob, w0, atol=2e-5):
    names, want = _fresh_solution(ob, w0)
    np.testing.assert_allclose(_sliders(ob, names), want, atol=atol)


def _drag_to(ob, drag, goal, moves=4):
    start = meshes.to_world(ob, manipulation.deformed_pin_positions(ob, bpy.context.evaluated_depsgraph_get())[:1])[0]
    for t in np.linspace(0.0, 1.0, moves + 1)[1:]:
        drag.move(ob, bpy.context.evaluated_depsgraph_get(), start + t * (goal - start))
    return drag.result


def _edit_key(ob, name, vertex=20, offset=(0.0, 0.0, 0.5), how="data"):
    kb = ob.data.shape_keys.key_blocks[name]
    if how == "co":
        kb.data[vertex].co = tuple(np.array(kb.data[vertex].co) + offset)
        return
    co = np.empty(len(ob.data.vertices) * 3, np.float32)
    kb.points.foreach_get("co", co)
    co[3 * vertex:3 * vertex + 3] += np.asarray(offset, dtype=np.float32)
    (kb.points if how == "points" else kb.data).foreach_set("co", co)


# =========================================================================== read once
def test_the_rig_is_read_once_for_drags_and_solve_pins(registered):
    ob = _pinned_sphere()
    goal = _world_goal(ob)
    manipulation.rig_model(ob)
    reads, checks = RIGS.reads, RIGS.verifications
    for _ in range(2):                                   # two drags, then the operator twice
        drag = manipulation.Drag(ob)
        drag.grab(ob, 0)
        _drag_to(ob, drag, goal)
        _assert_fresh(ob, drag.w0)
    target = meshes.to_local(ob, goal[None])[0]
    for _ in range(3):
        assert bpy.ops.shapespace.solve_pins(pin=0, target=target) == {"FINISHED"}
    assert RIGS.reads == reads
    if cache.EDITS_REPORTED:                             # ShapeSpace's own writes are not suspicious
        assert RIGS.verifications == checks


def test_a_slider_moved_by_hand_costs_a_checksum_not_a_read(registered):
    ob = _pinned_sphere()
    manipulation.rig_model(ob)
    reads, checks = RIGS.reads, RIGS.verifications
    ob.data.shape_keys.key_blocks["K2"].value = 0.7                # the UI's slider
    bpy.context.evaluated_depsgraph_get()
    model = manipulation.rig_model(ob)
    assert (RIGS.reads, RIGS.verifications) == (reads, checks + 1) or not cache.EDITS_REPORTED
    assert model.values[model.index("K2")] == pytest.approx(0.7)   # the cached model carries the sliders now


# =========================================================================== edits between and during drags
@pytest.mark.parametrize("how", ["data", "points", "co"])
def test_a_shape_key_edited_between_two_drags_is_seen(registered, how):
    ob = _pinned_sphere()
    goal = _world_goal(ob)
    drag = manipulation.Drag(ob)
    drag.grab(ob, 0)
    _drag_to(ob, drag, goal)
    reads = RIGS.reads
    _edit_key(ob, "K0", how=how)                                   # the pinned vertex moves with K0 now
    drag = manipulation.Drag(ob)
    drag.grab(ob, 0)
    _drag_to(ob, drag, goal)
    assert RIGS.reads == reads + 1
    _assert_fresh(ob, drag.w0)
    # and the operator, after another edit together with a slider change in the same update
    _edit_key(ob, "K3", vertex=20, offset=(0.3, 0.0, 0.0), how=how)
    ob.data.shape_keys.key_blocks["K1"].value = 0.25
    assert bpy.ops.shapespace.solve_pins(pin=0, target=meshes.to_local(ob, goal[None])[0]) == {"FINISHED"}
    assert RIGS.reads == reads + 2


def test_an_edit_during_a_drag_is_seen_at_the_next_move(registered):
    ob = _pinned_sphere()
    goal = _world_goal(ob)
    drag = manipulation.Drag(ob)
    drag.grab(ob, 0)
    _drag_to(ob, drag, goal, moves=2)
    _edit_key(ob, "K1", offset=(0.0, -0.4, 0.2))
    drag.move(ob, bpy.context.evaluated_depsgraph_get(), goal)
    _assert_fresh(ob, drag.w0)


@pytest.mark.parametrize("change", ["add", "delete", "rename", "range", "mute"])
def test_keys_added_deleted_renamed_or_reranged_mid_drag(registered, change):
    ob = _pinned_sphere()
    goal = _world_goal(ob)
    drag = manipulation.Drag(ob)
    drag.grab(ob, 0)
    _drag_to(ob, drag, goal, moves=2)
    blocks = ob.data.shape_keys.key_blocks
    if change == "add":
        base = np.empty(len(ob.data.vertices) * 3, np.float32)
        blocks["Basis"].points.foreach_get("co", base)
        base[3 * 20 + 2] += 0.6
        kb = ob.shape_key_add(name="New")
        kb.points.foreach_set("co", base)
        kb.value = 0.0
    elif change == "delete":
        ob.shape_key_remove(blocks["K0"])
    elif change == "rename":
        blocks["K0"].name, blocks["K3"].name = "tmp", "K0"
        blocks["tmp"].name = "K3"
    elif change == "range":
        blocks["K1"].slider_max = 0.1
    else:
        blocks["K3"].mute = True
    result = drag.move(ob, bpy.context.evaluated_depsgraph_get(), goal)
    names = shapekeys.slider_names(ob)
    assert list(drag.model.names) == names and len(result.weights) == len(names)
    _assert_fresh(ob, drag.w0)
    if change == "range":
        assert _sliders(ob, ["K1"])[0] <= 0.1 + 1e-7
    drag.cancel(ob)                                  # puts back the sliders that still exist
    assert np.all(_sliders(ob) == 0.0)


# =========================================================================== deformers: toggles and poses
def _armature_sphere(still=(40, 90)):
    ob = _pinned_sphere(still=still)
    arm = bpy.data.objects.new("Rig", bpy.data.armatures.new("Rig"))
    bpy.context.scene.collection.objects.link(arm)
    bpy.context.view_layer.objects.active = arm
    bpy.ops.object.mode_set(mode="EDIT")
    bone = arm.data.edit_bones.new("Bone")
    bone.head, bone.tail = (0.0, 0.0, -1.0), (0.0, 0.0, 1.0)
    bpy.ops.object.mode_set(mode="OBJECT")
    group = ob.vertex_groups.new(name="Bone")
    co = np.empty(len(ob.data.vertices) * 3, np.float32)
    ob.data.vertices.foreach_get("co", co)
    for v, z in enumerate(co[2::3]):
        group.add([v], float(0.4 + 0.3 * (z + 1.0)), "REPLACE")       # weights 0.4–1.0: a real blend
    mod = ob.modifiers.new("Armature", "ARMATURE")
    mod.object = arm
    _pose(arm, (0.5, 0.2, 0.3))
    bpy.context.view_layer.objects.active = ob
    return ob, arm, mod


def _pose(arm, euler):
    pb = arm.pose.bones["Bone"]
    pb.rotation_mode = "XYZ"
    pb.rotation_euler = euler
    bpy.context.view_layer.update()


def _lands_on(ob, goal, v=20, tol=2e-3):
    got = meshes.to_world(ob, evaluated(ob)[v][None])[0]
    assert np.linalg.norm(got - goal) < tol, (got, goal)


def test_modifier_toggled_and_pose_changed_mid_drag(registered):
    ob, arm, mod = _armature_sphere(still=())
    ob.shapespace.alpha, ob.shapespace.mu = 1e-6, 1e-8
    drag = manipulation.Drag(ob)
    drag.grab(ob, 0)
    goal = _world_goal(ob)
    _drag_to(ob, drag, goal)
    _lands_on(ob, goal)
    state = RIGS.peek(ob).derived["deform"].state
    for step in ("pose", "off", "on"):
        if step == "pose":
            _pose(arm, (-0.3, 0.4, 0.1))
        else:
            mod.show_viewport = step == "on"
            bpy.context.view_layer.update()
        goal = _world_goal(ob, w=(0.2, 0.5, 0.3, 0.1))
        drag.move(ob, bpy.context.evaluated_depsgraph_get(), goal)
        _lands_on(ob, goal)
    assert RIGS.peek(ob).derived["deform"].state != state          # rebuilt for the new pose


def test_overlay_reads_no_model_while_sliders_change(registered, monkeypatch):
    """The overlay draws from Blender's evaluated pin vertices and the crazy-space map cached per pose."""
    ob, arm, mod = _armature_sphere()
    at_rest = evaluated(ob)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    current, goal, still = manipulation.overlay_points(ob, depsgraph)    # builds the map (needs the model once)
    np.testing.assert_allclose(goal, current, atol=1e-5)       # pins added where they were: targets = positions
    monkeypatch.setattr(manipulation.RIGS, "model", lambda *a: pytest.fail("the overlay read the model"))
    monkeypatch.setattr(shapekeys, "read_blendshape_model", lambda *a, **k: pytest.fail("read the rig"))
    for w in ((0.3, 0.0, 0.6, 0.1), (0.0, 0.9, 0.2, 0.0)):
        shapekeys.write_slider_values(ob, ["K0", "K1", "K2", "K3"], w)
        depsgraph = bpy.context.evaluated_depsgraph_get()
        current, goal, still = manipulation.overlay_points(ob, depsgraph)
        np.testing.assert_allclose(current[0], evaluated(ob)[20], atol=1e-6)
        # the stationary pins' targets are their positions at zero sliders: drawn there, through the pose
        np.testing.assert_allclose(goal[1:], at_rest[[40, 90]], atol=1e-4)
    assert still.tolist() == [False, True, True]


# =========================================================================== undo, renames, two objects, reloads
def test_undo_during_and_after_a_drag(registered):
    bpy.ops.ed.undo_push(message="empty")
    ob = _pinned_sphere()
    bpy.ops.ed.undo_push(message="rig")
    _edit_key(ob, "K0", offset=(0.0, 0.0, 0.8))
    bpy.ops.ed.undo_push(message="edited K0")
    goal = _world_goal(ob)
    drag = manipulation.Drag(ob)
    drag.grab(ob, 0)
    _drag_to(ob, drag, goal, moves=2)
    bpy.ops.ed.undo()                                              # during the drag: back to the unedited K0
    assert len(RIGS) == 0
    ob = bpy.data.objects["Face"]
    reads = RIGS.reads
    drag.move(ob, bpy.context.evaluated_depsgraph_get(), goal)
    assert RIGS.reads == reads + 1
    _assert_fresh(ob, drag.w0)
    bpy.ops.ed.undo_push(message="dragged")
    _edit_key(ob, "K2", offset=(0.4, 0.0, 0.0))
    bpy.ops.ed.undo_push(message="edited K2")
    assert bpy.ops.shapespace.solve_pins() == {"FINISHED"}
    bpy.ops.ed.undo()                                              # after the drag: K2 as it was
    ob = bpy.data.objects["Face"]
    w0 = _sliders(ob)
    assert bpy.ops.shapespace.solve_pins() == {"FINISHED"}
    _assert_fresh(ob, w0, atol=5e-5)


def test_a_renamed_object_keeps_its_cache_and_a_namesake_gets_its_own(registered):
    ob = _pinned_sphere()
    manipulation.rig_model(ob)
    reads = RIGS.reads
    ob.name = "Renamed"
    assert bpy.ops.shapespace.solve_pins() == {"FINISHED"}
    assert RIGS.reads == reads
    other = _pinned_sphere("Face", seed=3)                         # a new object under the old name
    assert other.name == "Face"
    assert bpy.ops.shapespace.solve_pins() == {"FINISHED"}
    assert RIGS.reads == reads + 1
    _assert_fresh(other, np.zeros(4))


def test_two_objects_with_pins_in_one_scene(registered):
    a = _pinned_sphere("A", seed=1)
    b = _pinned_sphere("B", seed=2)
    for ob, seed_w in ((a, (0.5, 0.1, 0.3, 0.0)), (b, (0.0, 0.4, 0.2, 0.6)), (a, (0.2, 0.2, 0.2, 0.2))):
        goal = _world_goal(ob, w=seed_w)
        bpy.context.view_layer.objects.active = ob
        drag = manipulation.Drag(ob)
        drag.grab(ob, 0)
        _drag_to(ob, drag, goal, moves=2)
        _assert_fresh(ob, drag.w0)
        assert bpy.ops.shapespace.solve_pins() == {"FINISHED"}
    assert len(RIGS) == 2


def test_a_file_reloaded_with_the_same_names_is_read_again(registered, tmp_path):
    ob = _pinned_sphere()
    first = str(tmp_path / "first.blend")
    bpy.ops.wm.save_as_mainfile(filepath=first)
    _edit_key(ob, "K0", offset=(0.0, 0.0, 0.7))
    second = str(tmp_path / "second.blend")
    bpy.ops.wm.save_as_mainfile(filepath=second)
    for path in (first, second, first):
        bpy.ops.wm.open_mainfile(filepath=path)
        assert len(RIGS) == 0
        ob = bpy.data.objects["Face"]
        bpy.context.view_layer.objects.active = ob
        target = np.array(ob.shapespace.pins[0].target) + (0.0, 0.0, 0.3)
        assert bpy.ops.shapespace.solve_pins(pin=0, target=target) == {"FINISHED"}
        _assert_fresh(ob, np.zeros(4))


def test_without_the_handlers_every_use_is_verified(registered):
    """A cache nobody tells about depsgraph updates checks the checksum at every use (and notices edits)."""
    cache = manipulation.RigCache()
    ob = _pinned_sphere()
    first = cache.model(ob)
    assert cache.model(ob) is first and cache.verifications == 1
    _edit_key(ob, "K1", offset=(0.1, 0.0, 0.0))
    second = cache.model(ob)
    assert second is not first and cache.reads == 2
    v = 20
    assert second.deltas[1, v, 0] == pytest.approx(first.deltas[1, v, 0] + 0.1, abs=1e-6)


def test_ray_picking_matches_blenders_bvh(registered):
    from mathutils import Vector
    from mathutils.bvhtree import BVHTree

    from shapespace.bridge.manipulation import surface

    ob = _sphere()
    ob.rotation_euler = (0.3, -0.2, 0.5)
    bpy.context.view_layer.update()
    depsgraph = bpy.context.evaluated_depsgraph_get()
    tree = BVHTree.FromObject(ob, depsgraph)
    rng = np.random.default_rng(5)
    for _ in range(20):
        origin = rng.normal(size=3) * 4
        direction = -origin + rng.normal(size=3) * 0.3
        hit = manipulation.surface_pin(ob, depsgraph, origin, direction)
        inv = surface.inverse_world(ob)
        loc, _n, _i, _d = tree.ray_cast(Vector(inv[:3, :3] @ origin + inv[:3, 3]), Vector(inv[:3, :3] @ direction))
        assert (hit is None) == (loc is None)
        if hit is not None:
            pin, world = hit
            np.testing.assert_allclose(world, meshes.to_world(ob, np.array(loc)[None])[0], atol=1e-5)
            model = shapekeys.read_blendshape_model(ob)
            np.testing.assert_allclose(meshes.to_world(ob, pin_positions(model, [pin], model.values))[0], world,
                                       atol=1e-5)


# =========================================================================== issue #26 item 14: production scale
def test_a_drag_on_ict_facekit_reads_and_verifies_nothing_per_move(registered):
    """The drag's own slider writes (and the Solve Pins operator's) are never taken for outside edits on a
    production face either: no checksum, no read after mouse-down — the cost that grows with the rig."""
    import_file(shared("ict_facekit", "ict_facekit_expressions.glb"))
    ob = bpy.data.objects["ICTFace"]
    key = ob.data.shape_keys
    if key.animation_data is not None:
        key.animation_data.action = None
    ob.shapespace.mode = "DIRECT"
    bpy.context.view_layer.objects.active = ob
    model = manipulation.rig_model(ob)
    jaw = model.index("jawOpen")
    v = int(np.argmax(np.linalg.norm(model.deltas[jaw], axis=1)))
    manipulation.add_pin(ob, Pin.at_vertex(v))
    w = np.zeros(model.n_targets)
    w[jaw] = 0.5
    goal = _world_goal(ob, v=v, w=w)
    manipulation.rig_model(ob)
    reads, checks = RIGS.reads, RIGS.verifications
    drag = manipulation.Drag(ob)
    drag.grab(ob, 0)
    _drag_to(ob, drag, goal, moves=12)
    target = meshes.to_local(ob, goal[None])[0]
    assert bpy.ops.shapespace.solve_pins(pin=0, target=target) == {"FINISHED"}
    assert RIGS.reads == reads
    if cache.EDITS_REPORTED:
        assert RIGS.verifications == checks
    reached = meshes.to_world(ob, evaluated(ob)[v][None])[0]            # Blender's evaluation: the pin got there
    assert np.linalg.norm(reached - goal) < 1e-3 * np.ptp(evaluated(ob), axis=0).max()


@pytest.mark.parametrize("how", ["data", "points"])
def test_a_key_edited_by_a_script_just_before_a_use_is_seen(registered, how):
    """An edit not yet evaluated (a script's bulk write, then Solve Pins at once) was not yet reported by the
    depsgraph, so the cache trusted its stale model."""
    ob = _pinned_sphere()
    manipulation.rig_model(ob)
    bpy.context.evaluated_depsgraph_get()
    _edit_key(ob, "K0", how=how)                       # no evaluation in between
    model = manipulation.rig_model(ob)
    fresh = shapekeys.read_blendshape_model(ob)
    np.testing.assert_array_equal(model.deltas, fresh.deltas)
