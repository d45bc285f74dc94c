"""Issue #25 item 2: Symmetric pin-and-drag on a rig face (the Pin tool over ``bridge.rig.tool``).

The hybrid rig of ``rigs.py`` (facecap's head, a jaw bone, six shape keys; the head sits in the scene rotated and
scaled by its glTF import) with a mirror map built on it.  Ground truth is Blender's evaluation: the dragged pin
and its mirror pin are read back from the depsgraph-evaluated mesh; the reflection is the analytic one — the map's
rest plane ``x_axis = offset`` carried into world space by the object's matrix and, for a turned head, by the head
bone's deformation (a rigid transform of every vertex by a second Armature modifier, computed from the bone's
matrices) — never the plane the code fitted.
"""
import numpy as np
import pytest

import rigs
from blender_support import bpy
from shapespace.bridge import manipulation, symmetry
from shapespace.bridge import rig as brig
from shapespace.bridge.rig import tool
from shapespace.core.manipulation import Pin
from test_rig import _assert_same_state, _state
from test_rig_drag import _fcurve_keys
from test_rig_pin_tool import _drag, _face, _pins_world

RECOVERY_TOL = 1e-3


def _symmetric_face():
    """The hybrid face with a stored mirror map (every vertex mapped), Symmetric on."""
    rig = _face("hybrid")
    mmap = symmetry.build_map(rig.mesh, "POSITION", centre="BOUNDS", tolerance=1e-2)
    assert (mmap.mirror >= 0).all()
    symmetry.store_map(rig.mesh, mmap)
    rig.mesh.shapespace.symmetric = True
    return rig, mmap


def _rest_plane_world(ob, mmap, T=None):
    """The map's rest plane x_axis = offset in world space through ``T`` @ matrix_world (affine): (unit normal,
    offset), from the object's matrices alone."""
    M = (np.eye(4) if T is None else T) @ np.array(ob.matrix_world, dtype=np.float64)
    e = np.zeros(3)
    e[mmap.axis] = 1.0
    n = np.linalg.inv(M[:3, :3]).T @ e
    n /= np.linalg.norm(n)
    on = np.zeros(3)
    on[mmap.axis] = mmap.offset
    return n, float(n @ (M[:3, :3] @ on + M[:3, 3]))


def _reflect(p, plane):
    n, d = plane
    return p - 2.0 * (p @ n - d) * n


def _asymmetry(world, mmap, plane, moved):
    """Max over the vertices ``moved`` of ‖reflection of p_i − p_mirror(i)‖."""
    i = np.flatnonzero(moved)
    refl = world[i] - 2.0 * ((world[i] @ plane[0]) - plane[1])[:, None] * plane[0]
    return float(np.linalg.norm(refl - world[mmap.mirror[i]], axis=1).max())


def _left_smile_vertex(rig, mmap, pose):
    """The vertex on the left of the plane that ``pose`` moves most, its posed position, the rest surface."""
    c0 = brig.read_controls(rig.controls)
    rest = rig.world_points()
    brig.apply_controls(rig.controls, pose)
    posed = rig.world_points()
    brig.apply_controls(rig.controls, c0)
    moved = np.linalg.norm(posed - rest, axis=1)
    co = symmetry.rest_positions(rig.mesh)[:, mmap.axis] - mmap.offset
    smile = np.where(co > 0.05 * np.ptp(co), moved, 0.0)
    v = int(np.argmax(smile))
    return v, posed[v], rest


def _pose(rig, **values):
    c = brig.read_controls(rig.controls)
    for k, v in values.items():
        c[[ch.name for ch in rig.controls.channels].index(k)] = v
    return c


def test_symmetric_drag_moves_the_mirror_pin_to_the_reflected_target_and_keeps_the_face_symmetric(registered):
    rig, mmap = _symmetric_face()
    ob = rig.mesh
    pose = _pose(rig, **{"jaw rotation X": 0.12, "key mouthSmile_L": 0.6, "key mouthSmile_R": 0.6})
    v, target, rest = _left_smile_vertex(rig, mmap, pose)
    diag = rigs.diagonal(rest)
    plane = _rest_plane_world(ob, mmap)
    drag = tool.drag_for(ob)
    index = tool.add_pin(ob, drag, Pin.at_vertex(v))                          # a click: the pin and its mirror pin
    links = manipulation.mirror_links(ob)
    assert len(links) == 2 and links.tolist() == [1, 0]
    assert manipulation.read_pin_state(ob).vertices[1, 0] == mmap.mirror[v]
    drag = _drag(rig, index, drag, target)
    assert drag.mirror == 1
    shown = _pins_world(rig)
    assert np.linalg.norm(shown[0] - target) / diag <= RECOVERY_TOL
    assert np.linalg.norm(shown[1] - _reflect(target, plane)) / diag <= RECOVERY_TOL
    assert np.linalg.norm(target - _reflect(target, plane)) / diag > 0.05     # the two targets are far apart
    # the result is mirror-symmetric where the rig is: the moved region's asymmetry stays at the head's own
    world = rig.world_points()
    moved = np.linalg.norm(world - rest, axis=1) > 1e-3 * diag
    before = _asymmetry(rest, mmap, plane, moved)
    after = _asymmetry(world, mmap, plane, moved)
    assert after - before <= 2e-3 * diag, (before / diag, after / diag)
    c = brig.read_controls(rig.controls)
    names = [ch.name for ch in rig.controls.channels]
    assert abs(c[names.index("key mouthSmile_L")] - c[names.index("key mouthSmile_R")]) <= 0.05
    # the same drag without Symmetric leaves the right side behind: that is what the mirror pin prevented
    tool.finish(drag, ob, 1, autokey=False)
    brig.apply_controls(rig.controls, brig.read_controls(rig.controls) * 0.0)
    manipulation.clear_pins(ob)
    ob.shapespace.symmetric = False
    drag = tool.drag_for(ob)
    drag = _drag(rig, tool.add_pin(ob, drag, Pin.at_vertex(v)), drag, target)
    assert len(ob.shapespace.pins) == 1
    lone = rig.world_points()
    assert _asymmetry(lone, mmap, plane, moved) - before > 5.0 * max(after - before, 1e-4 * diag)


def _turn_head(rig, rotation):
    """A second Armature modifier with one ``turn`` bone weighting every vertex 1 (after the jaw's; not named
    ``head``: the hybrid's own armature has a head bone and group): that bone turned by ``rotation`` (Euler XYZ).
    Returns the rigid world transform (4, 4) it applies to the face."""
    ob = rig.mesh
    rest = rig.world_points()
    centre = 0.5 * (rest.min(0) + rest.max(0))
    arm = rigs._armature("Neck", {"turn": (tuple(centre - [0, 0, 0.3]), tuple(centre))})
    group = ob.vertex_groups.new(name="turn")
    group.add(list(range(len(ob.data.vertices))), 1.0, "REPLACE")
    mod = ob.modifiers.new("Head", "ARMATURE")
    mod.object = arm
    pb = arm.pose.bones["turn"]
    pb.rotation_mode = "XYZ"
    pb.rotation_euler = rotation
    bpy.context.view_layer.objects.active = ob
    bpy.context.view_layer.update()
    W = np.array(arm.matrix_world, dtype=np.float64)
    T = W @ np.array(pb.matrix, dtype=np.float64) @ np.linalg.inv(np.array(pb.bone.matrix_local)) @ np.linalg.inv(W)
    np.testing.assert_allclose(rig.world_points(), rest @ T[:3, :3].T + T[:3, 3], atol=1e-5 * rigs.diagonal(rest))
    return T


def test_a_turned_head_reflects_across_its_turned_plane(registered):
    rig, mmap = _symmetric_face()
    ob = rig.mesh
    pose = _pose(rig, **{"jaw rotation X": 0.1, "key mouthSmile_L": 0.5, "key mouthSmile_R": 0.5})
    v, _, _ = _left_smile_vertex(rig, mmap, pose)
    T = _turn_head(rig, (0.15, 0.5, -0.3))
    plane = _rest_plane_world(ob, mmap, T)
    upright = _rest_plane_world(ob, mmap)
    assert np.degrees(np.arccos(abs(plane[0] @ upright[0]))) > 20.0          # the plane really turned
    brig.apply_controls(rig.controls, pose)
    target = rig.world_points()[v]
    brig.apply_controls(rig.controls, pose * 0.0)
    diag = rigs.diagonal(rig.world_points())
    drag = tool.drag_for(ob)
    index = tool.add_pin(ob, drag, Pin.at_vertex(v))
    drag = _drag(rig, index, drag, target)
    fitted = drag.rig.plane                                                   # fitted at mouse-down
    assert np.degrees(np.arccos(min(1.0, abs(fitted.normal @ plane[0])))) < 0.05
    shown = _pins_world(rig)
    assert np.linalg.norm(shown[0] - target) / diag <= RECOVERY_TOL
    assert np.linalg.norm(shown[1] - _reflect(target, plane)) / diag <= RECOVERY_TOL
    assert np.linalg.norm(_reflect(target, plane) - _reflect(target, upright)) / diag > 0.05


def test_a_centre_line_pin_is_held_on_the_plane(registered):
    rig, mmap = _symmetric_face()
    ob = rig.mesh
    rest = rig.world_points()
    diag = rigs.diagonal(rest)
    brig.apply_controls(rig.controls, _pose(rig, **{"jaw rotation X": 0.2}))
    posed = rig.world_points()
    brig.apply_controls(rig.controls, _pose(rig))
    centre = np.flatnonzero(mmap.mirror == np.arange(len(mmap.mirror)))
    v = int(centre[np.argmax(np.linalg.norm(posed[centre] - rest[centre], axis=1))])
    plane = _rest_plane_world(ob, mmap)
    target = posed[v] + 0.02 * diag * plane[0]                                # off the plane
    drag = tool.drag_for(ob)
    index = tool.add_pin(ob, drag, Pin.at_vertex(v))
    assert manipulation.mirror_links(ob).tolist() == [0] and len(ob.shapespace.pins) == 1
    drag = _drag(rig, index, drag, target)
    on = target - (target @ plane[0] - plane[1]) * plane[0]
    assert np.linalg.norm(_pins_world(rig)[0] - on) / diag <= RECOVERY_TOL


def test_cancel_restores_every_channel_and_removes_both_new_pins(registered):
    rig, mmap = _symmetric_face()
    ob = rig.mesh
    pose = _pose(rig, **{"key mouthSmile_L": 0.7, "key mouthSmile_R": 0.7})
    v, target, rest = _left_smile_vertex(rig, mmap, pose)
    drag = tool.drag_for(ob)
    tool.add_pin(ob, drag, Pin.at_vertex(int(np.argmin(rest[:, 1]))), stationary=True)   # a pin pair in place
    pins_before = manipulation.read_pin_state(ob).key()
    links_before = manipulation.mirror_links(ob).tolist()
    before = _state(rig)
    drag = tool.drag_for(ob)
    index = tool.add_pin(ob, drag, Pin.at_vertex(v))
    assert len(ob.shapespace.pins) == len(links_before) + 2
    drag = _drag(rig, index, drag, target, moves=2)
    assert np.abs(rig.world_points() - before[4]).max() > 1e-3 * rigs.diagonal(rest)
    drag.cancel(ob)
    _assert_same_state(before, _state(rig))
    assert manipulation.read_pin_state(ob).key() == pins_before
    assert manipulation.mirror_links(ob).tolist() == links_before
    assert _fcurve_keys(rig) == {}
    # an existing linked pin: its drag is cancelled, both pins and every channel stay as they were
    index = tool.add_pin(ob, tool.drag_for(ob), Pin.at_vertex(v))
    pins_before = manipulation.read_pin_state(ob).key()
    drag = _drag(rig, index, False, target, moves=1)
    drag.cancel(ob)
    _assert_same_state(before, _state(rig))
    assert manipulation.read_pin_state(ob).key() == pins_before


def test_symmetric_without_a_mirror_map_is_refused_by_name(registered):
    rig, mmap = _symmetric_face()
    ob = rig.mesh
    v = int(np.flatnonzero(mmap.mirror != np.arange(len(mmap.mirror)))[0])
    drag = tool.drag_for(ob)
    index = tool.add_pin(ob, drag, Pin.at_vertex(v))
    del ob.data[symmetry.PROP]
    before = _state(rig)
    pins = manipulation.read_pin_state(ob).key()
    with pytest.raises(Exception) as exc:
        tool.drag_for(ob).grab(ob, index)
    assert "has no mirror map" in str(exc.value) and repr(ob.name) in str(exc.value)
    with pytest.raises(Exception) as exc:
        tool.add_pin(ob, tool.drag_for(ob), Pin.at_vertex(v))
    assert "has no mirror map" in str(exc.value)
    _assert_same_state(before, _state(rig))
    assert manipulation.read_pin_state(ob).key() == pins
