"""Issue #25 item 2 in the UI: the Pin tool (Drag Pins) on faces driven by a stored control set.

The modal operator's steps are driven through the bridge functions its handler calls (``bridge.rig.tool``: made at
mouse-down, ``add_pin`` for a click on the surface, ``grab``, ``move`` per mouse move, ``finish`` on release,
``cancel`` on Esc/right-click) — as ``test_symmetric_drag.py`` and ``test_manipulation_cache.py`` drive the linear
drag; its poll is called through ``bpy.ops``.  Ground truth is Blender's evaluation of the hybrid and driver rigs of
``rigs.py``: a random control pose's surface point is the dragged pin's target, pins on parts of the head that pose
leaves still are held, and after every move the pins are read back from the depsgraph-evaluated mesh.
"""
import os
import tempfile

import numpy as np
import pytest

import rigs
from blender_support import OPERATOR_CALLS, bpy, classify_operator_call
from shapespace.bridge import manipulation
from shapespace.bridge import rig as brig
from shapespace.bridge.rig import stored, tool
from shapespace.core.manipulation import Pin
from support import shared
from test_rig import _assert_same_state, _state
from test_rig_drag import _fcurve_keys

RECOVERY_TOL = 1e-3
BUILDERS = {"hybrid": rigs.hybrid_rig, "driver": rigs.driver_rig}


def _face(name):
    """The rig with its controls stored on the face, the face active in Object Mode, Direct mode."""
    rig = BUILDERS[name](shared(*rigs.FACECAP.split("/")))
    stored.add_entries_of(rig.mesh, rig.armature.name, rig.controls.channels)
    bpy.ops.object.select_all(action="DESELECT")
    rig.mesh.select_set(True)
    bpy.context.view_layer.objects.active = rig.mesh
    rig.mesh.shapespace.mode = "DIRECT"
    return rig


def _pins_world(rig):
    """Blender's evaluated world positions of the stored pins (k, 3)."""
    state = manipulation.read_pin_state(rig.mesh)
    world = rig.world_points()
    return np.einsum("kc,kcx->kx", state.weights, world[state.vertices])


def _pose_and_pins(rig, seed, held=3):
    """A random pose's target for the vertex it moves most, and ``held`` vertices that pose leaves still (within
    1e-7 of the diagonal); the rig is left at its start pose.  Returns (moving vertex, its target, held vertices)."""
    rng = np.random.default_rng(seed)
    c0 = brig.read_controls(rig.controls)
    rest = rig.world_points()
    diag = rigs.diagonal(rest)
    brig.apply_controls(rig.controls, rig.random_pose(rng))
    posed = rig.world_points()
    brig.apply_controls(rig.controls, c0)
    moved = np.linalg.norm(posed - rest, axis=1)
    still = np.flatnonzero(moved < 1e-7 * diag)
    assert moved.max() > 1e-2 * diag and still.size >= held
    return int(np.argmax(moved)), posed[int(np.argmax(moved))], rng.choice(still, held, replace=False), diag


def _drag(rig, index, created, target, moves=3):
    """Mouse-down on pin ``index``, ``moves`` mouse moves to ``target`` (world), as the tool does; returns the drag."""
    ob = rig.mesh
    drag = tool.drag_for(ob) if not isinstance(created, tool.RigPinDrag) else created
    drag.grab(ob, index, created is not False and created is not None)
    start = drag.targets[index].copy()
    for k in range(1, moves + 1):
        res = drag.move(ob, bpy.context.evaluated_depsgraph_get(), start + (target - start) * k / moves)
        hist = res.diagnostics["objective_history"]
        assert all(b <= a for a, b in zip(hist, hist[1:])), hist
        shown = _pins_world(rig)                          # the pins land where Blender draws them
        np.testing.assert_allclose(res.points, shown, atol=1e-6 * rigs.diagonal(rig.world_points()))
    ticks = 0
    while tool.rest(drag, ob):                            # the mouse rests: the tool's timer settles the deferred work
        ticks += 1
        assert ticks < 100
        np.testing.assert_allclose(drag.result.points, _pins_world(rig), atol=1e-6 * rigs.diagonal(rig.world_points()))
    return drag


@pytest.mark.parametrize("name", sorted(BUILDERS))
def test_pin_tool_drags_a_rig_face_lands_the_pin_holds_the_others_and_keys_the_changed_channels(registered, name):
    rig = _face(name)
    ob = rig.mesh
    moving, target, held, diag = _pose_and_pins(rig, 3)
    bpy.context.scene.frame_set(5)
    drag = tool.drag_for(ob)                                                   # mouse-down
    assert isinstance(drag, tool.RigPinDrag) and drag.model is None
    for v in held:                                                             # Shift-clicks: pins in place
        tool.add_pin(ob, drag, Pin.at_vertex(int(v)), stationary=True)
    held_at = _pins_world(rig)
    index = tool.add_pin(ob, drag, Pin.at_vertex(moving))                      # click on the surface
    before = brig.read_controls(rig.controls)
    drag = _drag(rig, index, drag, target)
    shown = _pins_world(rig)
    assert np.linalg.norm(shown[index] - target) / diag <= RECOVERY_TOL
    assert np.linalg.norm(shown[:index] - held_at, axis=1).max() / diag <= RECOVERY_TOL
    assert tool.report_text(drag)[0] in ("INFO", "WARNING")
    # the overlay draws the pins where Blender evaluates them, each its own target
    from shapespace.ui import overlay
    current, goal, still = overlay.pin_world_points(ob, bpy.context.evaluated_depsgraph_get())
    np.testing.assert_allclose(current, shown, atol=1e-6 * diag)
    np.testing.assert_array_equal(goal, current)
    assert still.tolist() == [True] * len(held) + [False]
    surface = rig.world_points()
    keyed = tool.finish(drag, ob, 5, autokey=True)                              # release with auto-key
    after = brig.read_controls(rig.controls)
    changed = np.flatnonzero(np.abs(after - before) > 0)
    assert keyed == len(changed) > 0
    keys = _fcurve_keys(rig)
    assert keys and all(len(k) == 1 and k[0][0] == 5.0 for k in keys.values())
    assert any(idb == rig.armature.name for idb, _, _ in keys)                   # on the armature's action
    bpy.context.scene.frame_set(1)
    bpy.context.scene.frame_set(5)                                             # the keys play the dragged pose
    np.testing.assert_allclose(rig.world_points(), surface, atol=1e-6 * diag)


@pytest.mark.parametrize("name", sorted(BUILDERS))
def test_cancel_restores_the_rig_exactly_removes_the_new_pin_and_keys_nothing(registered, name):
    rig = _face(name)
    ob = rig.mesh
    moving, target, held, diag = _pose_and_pins(rig, 11)
    drag = tool.drag_for(ob)
    tool.add_pin(ob, drag, Pin.at_vertex(int(held[0])), stationary=True)
    pins_before = manipulation.read_pin_state(ob).key()
    before = _state(rig)
    drag = tool.drag_for(ob)
    index = tool.add_pin(ob, drag, Pin.at_vertex(moving))
    drag = _drag(rig, index, drag, target, moves=2)
    assert np.abs(rig.world_points() - before[4]).max() > 1e-3 * diag         # the drag moved the face
    drag.cancel(ob)                                                            # Esc / right-click
    _assert_same_state(before, _state(rig))
    assert manipulation.read_pin_state(ob).key() == pins_before
    assert _fcurve_keys(rig) == {}
    drag = _drag(rig, 0, False, _pins_world(rig)[0] + 0.01 * diag, moves=1)    # an existing pin: kept on cancel
    drag.cancel(ob)
    _assert_same_state(before, _state(rig))
    assert manipulation.read_pin_state(ob).key() == pins_before


def test_release_without_auto_key_keeps_the_pose_and_keys_nothing(registered):
    rig = _face("hybrid")
    ob = rig.mesh
    moving, target, _held, diag = _pose_and_pins(rig, 4)
    drag = tool.drag_for(ob)
    drag = _drag(rig, tool.add_pin(ob, drag, Pin.at_vertex(moving)), drag, target, moves=1)
    shown = rig.world_points()
    assert tool.finish(drag, ob, 1, autokey=False) == 0
    assert _fcurve_keys(rig) == {}
    np.testing.assert_array_equal(rig.world_points(), shown)
    assert np.linalg.norm(_pins_world(rig)[0] - target) / diag <= RECOVERY_TOL


def _by_name(mesh, arm):
    m, a = bpy.data.objects[mesh], bpy.data.objects[arm]
    bpy.context.view_layer.update()
    dg = bpy.context.evaluated_depsgraph_get()
    me = m.evaluated_get(dg).to_mesh()
    co = np.empty(3 * len(me.vertices), np.float32)
    me.vertices.foreach_get("co", co)
    m.evaluated_get(dg).to_mesh_clear()
    pose = [(tuple(pb.location), tuple(pb.rotation_euler)) for pb in a.pose.bones]
    anim = a.animation_data is not None and a.animation_data.action is not None
    return co, pose, anim, len(m.shapespace.pins)


def test_undo_restores_the_pose_the_keys_and_the_pins(registered):
    rig = _face("driver")
    ob = rig.mesh
    names = (ob.name, rig.armature.name)
    moving, target, _held, _diag = _pose_and_pins(rig, 8)
    bpy.ops.ed.undo_push(message="before")
    before = _by_name(*names)
    drag = tool.drag_for(ob)
    drag = _drag(rig, tool.add_pin(ob, drag, Pin.at_vertex(moving)), drag, target, moves=1)
    assert tool.finish(drag, ob, 1, autokey=True) > 0
    bpy.ops.ed.undo_push(message="Drag Pins")                                 # what the operator's UNDO pushes
    after = _by_name(*names)
    assert after[2] and after[3] == 1 and not np.array_equal(after[0], before[0])
    bpy.ops.ed.undo()
    again = _by_name(*names)
    np.testing.assert_array_equal(again[0], before[0])
    assert again[1:] == before[1:]


def test_a_plain_shape_key_face_keeps_the_linear_drag(registered):
    rig = _face("hybrid")
    face = rig.mesh
    assert tool.uses_rig(face)
    stored.clear(face)                                                         # no control set: linear
    assert not tool.uses_rig(face) and isinstance(tool.drag_for(face), manipulation.Drag)
    own = [ch for ch in rig.controls.channels if ch.kind == "shape_key"]
    stored.add_entries_of(face, "", own)                                       # only its own sliders: linear
    assert not tool.uses_rig(face) and isinstance(tool.drag_for(face), manipulation.Drag)


def _poll_message():
    outcome, message = classify_operator_call("drag_pins", OPERATOR_CALLS.get("drag_pins", {}))
    assert outcome == "refused", (outcome, message)
    return message


def test_poll_names_what_is_missing(registered):
    rig = _face("hybrid")
    face = rig.mesh
    assert "3D Viewport" in _poll_message()                                    # a rig face is pinnable
    face.shapespace.mode = "LEARNED"                                          # Learned and Symmetric are rig modes too
    face.shapespace.symmetric = True                                           # (refusals: at mouse-down, by name)
    assert "3D Viewport" in _poll_message()
    face.shapespace.mode = "SLIDERS"
    assert "Switch the ShapeSpace mode to Direct or Learned" in _poll_message()
    face.shapespace.mode = "DIRECT"
    face.shapespace.symmetric = False
    bpy.ops.object.mode_set(mode="EDIT")
    assert f"'{face.name}' is in Edit Mode" in _poll_message()
    bpy.ops.object.mode_set(mode="OBJECT")
    rig.armature.pose.bones["jaw"].name = "gone"                              # a stored channel's bone is gone
    assert "jaw" in _poll_message()
    bpy.ops.mesh.primitive_cube_add()                                          # no shape keys, no control set
    assert "no shape keys and no control set" in _poll_message()


def test_poll_names_a_linked_armature(registered):
    rig = _face("hybrid")
    face, arm = rig.mesh, rig.armature
    path = os.path.join(tempfile.mkdtemp(prefix="ss-pin-"), "arm.blend")
    bpy.data.libraries.write(path, {arm}, fake_user=True)
    name = arm.name
    bpy.data.objects.remove(arm)
    with bpy.data.libraries.load(path, link=True) as (_, dst):
        dst.objects = [name]
    linked = dst.objects[0]
    bpy.context.scene.collection.objects.link(linked)
    for m in face.modifiers:
        if m.type == "ARMATURE":
            m.object = linked
    bpy.context.view_layer.objects.active = face
    with pytest.raises(RuntimeError) as exc:               # (classify_operator_call reads no linked armature)
        bpy.ops.shapespace.drag_pins()
    message = str(exc.value)
    assert "poll()" in message and "linked" in message and repr(name) in message
