"""Issue #25 item 2: pin-and-drag on bone-, driver- and hybrid-driven faces (bridge/rig/drag.py).

Ground truth is Blender's own evaluation: a random control pose of each test rig (tests/bridge/rigs.py) is
evaluated by the depsgraph and its surface points (vertices and barycentric points) are the drag's targets; after
the drag the rig is evaluated again by Blender (``Rig.world_points``) and every pin must be within 1e-3 of the
head's diagonal.  Keys are read back from the F-Curves; cancel must give back the rig exactly.
"""
import numpy as np
import pytest

import rigs
from blender_support import bpy
from shapespace.bridge import actions
from shapespace.bridge import rig as brig
from shapespace.core.manipulation import Pin
from shapespace.core.result import ShapeSpaceError
from support import shared
from test_rig import _assert_same_state, _state

RECOVERY_TOL = 1e-3


def _head():
    return shared(*rigs.FACECAP.split("/"))


def _surface_pins(rig, count, rng):
    """``count`` pins spread over the channels: every other one a barycentric point of a triangle of its vertex."""
    verts = rigs.pin_vertices(rig, count, rng)
    me = rig.mesh.data
    me.calc_loop_triangles()
    tris = np.empty(len(me.loop_triangles) * 3, np.int64)
    me.loop_triangles.foreach_get("vertices", tris)
    tris = tris.reshape(-1, 3)
    pins = []
    for k, v in enumerate(verts):
        if k % 2:
            tri = tris[np.flatnonzero((tris == v).any(1))[0]]
            pins.append(Pin(tuple(int(i) for i in tri), (0.6, 0.25, 0.15)))
        else:
            pins.append(Pin.at_vertex(int(v)))
    return pins


def _pin_points(world, pins):
    return np.array([sum(w * world[v] for v, w in zip(p.vertices, p.weights)) for p in pins])


def _fcurve_keys(rig):
    """{(datablock name, data path, index): [(frame, value)]} of every F-Curve on the rig's actions."""
    out = {}
    for idb in (rig.armature, rig.mesh, rig.mesh.data.shape_keys):
        action = actions.active_action(idb)
        for fc in actions.fcurves(action, idb):
            out[(idb.name, fc.data_path, fc.array_index)] = [tuple(k.co) for k in fc.keyframe_points]
    return out


def _drag_to_random_pose(rig, seed, count, moves=4):
    """Drag from the current pose to a random pose's surface points in ``moves`` mouse moves; return the drag,
    the pins, the targets, the diagonal and every move's result."""
    rng = np.random.default_rng(seed)
    pins = _surface_pins(rig, count, rng)
    c0 = brig.read_controls(rig.controls)
    diag = rigs.diagonal(rig.world_points())
    brig.apply_controls(rig.controls, rig.random_pose(rng))
    targets = _pin_points(rig.world_points(), pins)
    brig.apply_controls(rig.controls, c0)
    drag = brig.RigDrag(rig.mesh, rig.controls)
    start = drag.begin(pins)
    np.testing.assert_allclose(start, _pin_points(rig.world_points(), pins), atol=1e-6 * diag)
    results = []
    for k in range(1, moves + 1):
        res = drag.move(start + (targets - start) * k / moves)
        hist = res.diagnostics["objective_history"]
        assert all(b <= a for a, b in zip(hist, hist[1:])), hist
        # the pins land where Blender draws them: the solve's verified points are the evaluated mesh's
        np.testing.assert_allclose(res.points, _pin_points(rig.world_points(), pins), atol=1e-6 * diag)
        np.testing.assert_allclose(brig.read_controls(rig.controls), res.x, rtol=1e-6, atol=1e-7)   # float32
        results.append(res)
    return drag, pins, targets, diag, results


def _assert_landed(rig, pins, targets, diag):
    err = np.linalg.norm(_pin_points(rig.world_points(), pins) - targets, axis=1).max() / diag
    assert err <= RECOVERY_TOL, err


def _assert_keys_are_the_changed_channels(rig, drag, before, keyed, frame):
    after = brig.read_controls(rig.controls)
    changed = np.flatnonzero(np.abs(after - before) > 0)
    assert sorted(keyed) == sorted(rig.controls.channels[i].name for i in changed)
    keys = _fcurve_keys(rig)
    expected = {}
    for i in changed:
        b = brig.bind(rig.controls)[i]
        ch = b.channel
        if ch.path.startswith("data.shape_keys."):
            idb, path = rig.mesh.data.shape_keys, ch.path[len("data.shape_keys."):]
        else:
            idb, path = b.object, ch.path
        raw = b.raw()
        if ch.kind == "rotation" and ch.rotation_mode in ("QUATERNION", "AXIS_ANGLE"):
            for k in range(4):
                expected[(idb.name, path, k)] = raw[k]
        else:
            expected[(idb.name, path, max(ch.index, 0))] = raw if ch.index < 0 else raw[ch.index]
    assert set(keys) == set(expected)
    for name, value in expected.items():
        assert len(keys[name]) == 1 and keys[name][0][0] == frame
        assert keys[name][0][1] == pytest.approx(value, abs=1e-6)


@pytest.mark.parametrize("builder,count", [(rigs.hybrid_rig, 12), (rigs.driver_rig, 8)], ids=["hybrid", "driver"])
def test_drag_lands_every_pin_and_release_keys_exactly_the_changed_channels(builder, count):
    rig = builder(_head())
    bpy.context.scene.frame_set(7)
    before = brig.read_controls(rig.controls)
    drag, pins, targets, diag, _ = _drag_to_random_pose(rig, 5, count)
    keyed = drag.release(autokey=True)                   # the pins land at release (moves may trail: module doc)
    _assert_landed(rig, pins, targets, diag)
    shown = rig.world_points()
    _assert_keys_are_the_changed_channels(rig, drag, before, keyed, 7.0)
    bpy.context.scene.frame_set(1)
    bpy.context.scene.frame_set(7)                       # the keys play back the dragged pose
    np.testing.assert_allclose(rig.world_points(), shown, atol=1e-6 * diag)


@pytest.mark.rigify
@pytest.mark.gltf_export                                   # bpy 4.2 exit guard after Rigify (see test_rig.py)
def test_rigify_drag_lands_every_pin_and_keys_all_four_quaternion_components():
    rig = rigs.rigify_rig(_head())
    assert rig.controls.channels[0].rotation_mode == "QUATERNION"
    before = brig.read_controls(rig.controls)
    drag, pins, targets, diag, _ = _drag_to_random_pose(rig, 13, 20)
    keyed = drag.release()
    _assert_landed(rig, pins, targets, diag)
    assert "jaw_master rotation X" in keyed
    _assert_keys_are_the_changed_channels(rig, drag, before, keyed, float(bpy.context.scene.frame_current))


def test_cancel_restores_the_rig_exactly_and_keys_nothing():
    rig = rigs.driver_rig(_head())
    before = _state(rig)
    actions_before = len(bpy.data.actions)
    drag, *_ = _drag_to_random_pose(rig, 9, 6, moves=2)
    assert np.abs(rig.world_points() - before[4]).max() > 1e-3 * rigs.diagonal(before[4])   # the drag moved it
    drag.cancel()
    _assert_same_state(before, _state(rig))
    assert len(bpy.data.actions) == actions_before and _fcurve_keys(rig) == {}
    with pytest.raises(ShapeSpaceError, match="not active"):
        drag.release()


def test_release_without_autokey_keeps_the_pose_and_keys_nothing():
    rig = rigs.hybrid_rig(_head())
    drag, pins, targets, diag, _ = _drag_to_random_pose(rig, 21, 6, moves=1)
    assert drag.release(autokey=False) == []
    _assert_landed(rig, pins, targets, diag)
    assert _fcurve_keys(rig) == {}


def test_a_failed_move_keeps_the_last_controls_and_nothing_is_keyed():
    rig = rigs.hybrid_rig(_head())
    drag, pins, targets, diag, results = _drag_to_random_pose(rig, 4, 6, moves=2)
    bad = targets.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ShapeSpaceError, match="pin 3"):
        drag.move(bad)
    np.testing.assert_allclose(brig.read_controls(rig.controls), results[-1].x, rtol=1e-6, atol=1e-7)
    with pytest.raises(ShapeSpaceError, match="expected"):
        drag.move(targets[:2])
    drag.cancel()
    assert _fcurve_keys(rig) == {}


@pytest.mark.parametrize("which", ["armature", "mesh"])
def test_edit_mode_is_refused_by_name_and_changes_nothing(which):
    rig = rigs.hybrid_rig(_head())
    ob = rig.armature if which == "armature" else rig.mesh
    bpy.context.view_layer.objects.active = ob
    bpy.ops.object.mode_set(mode="EDIT")
    before = brig.read_controls(rig.controls)
    drag = brig.RigDrag(rig.mesh, rig.controls)
    with pytest.raises(ShapeSpaceError, match=f"{ob.name!r} is in Edit Mode"):
        drag.begin([0, 1, 2, 3, 4])
    np.testing.assert_array_equal(brig.read_controls(rig.controls), before)
    assert ob.mode == "EDIT" and _fcurve_keys(rig) == {}


@pytest.mark.parametrize("mode", ["OBJECT", "POSE"])
def test_drag_works_in_object_and_pose_mode(mode):
    rig = rigs.hybrid_rig(_head())
    bpy.context.view_layer.objects.active = rig.armature
    bpy.ops.object.mode_set(mode=mode)
    before = brig.read_controls(rig.controls)
    drag, pins, targets, diag, _ = _drag_to_random_pose(rig, 17, 5, moves=2)
    keyed = drag.release()
    _assert_landed(rig, pins, targets, diag)
    assert rig.armature.mode == mode
    _assert_keys_are_the_changed_channels(rig, drag, before, keyed, float(bpy.context.scene.frame_current))


def test_small_moves_reuse_the_cached_jacobian():
    """The first move computes the pins' Jacobian; the following small moves start from the cached one (Broyden
    updates) and mostly need no new one — far fewer rig evaluations than a Jacobian's one per channel."""
    rig = rigs.hybrid_rig(_head())
    drag, pins, targets, diag, results = _drag_to_random_pose(rig, 33, 10, moves=20)
    assert results[0].jacobians >= 1
    later = results[1:]
    assert sum(r.jacobians for r in later) < len(later) // 2, [r.jacobians for r in later]
    assert np.median([r.evaluations for r in later]) < len(rig.controls), [r.evaluations for r in later]
    _assert_landed(rig, pins, targets, diag)
    drag.cancel()


def test_moves_defer_jacobian_refreshes_and_release_settles_where_a_full_solve_lands():
    """After the first move no move computes a Jacobian and each makes one verified step: a jump the cached
    Jacobian cannot follow (past the peak of the driver rig's in-between hat, up the ``sin`` and ``var + 2 var²``
    drivers) stops short with its verified controls, and the release settles: its solve lands every pin, each of
    its steps verified, and the keys hold the settled pose."""
    rig = rigs.driver_rig(_head())
    pins = _surface_pins(rig, 8, np.random.default_rng(9))
    diag = rigs.diagonal(rig.world_points())
    c0 = brig.read_controls(rig.controls)
    brig.apply_controls(rig.controls, [0.45, 0.45, 0.05, 0.55, 0.9])
    targets = _pin_points(rig.world_points(), pins)
    brig.apply_controls(rig.controls, c0)
    drag = brig.RigDrag(rig.mesh, rig.controls)
    start = drag.begin(pins)
    first = drag.move(start + (targets - start) * 0.01)
    assert first.jacobians >= 1
    jump = drag.move(targets)                                       # the whole way at once on the cached Jacobian
    assert jump.jacobians == 0 and jump.evaluations == 1            # one verified step per move
    hist = jump.diagnostics["objective_history"]
    assert all(b <= a for a, b in zip(hist, hist[1:]))
    np.testing.assert_allclose(jump.points, _pin_points(rig.world_points(), pins), atol=1e-6 * diag)
    assert jump.status != 0 and jump.pin_error_max > RECOVERY_TOL * diag     # short of the targets
    keyed = drag.release()
    settled = drag.result
    assert settled is not jump and settled.jacobians >= 1 and settled.status == 0
    hist = settled.diagnostics["objective_history"]
    assert all(b <= a for a, b in zip(hist, hist[1:]))
    _assert_landed(rig, pins, targets, diag)
    assert keyed
    shown = rig.world_points()
    bpy.context.scene.frame_set(bpy.context.scene.frame_current + 1)
    bpy.context.scene.frame_set(bpy.context.scene.frame_current - 1)
    np.testing.assert_allclose(rig.world_points(), shown, atol=1e-6 * diag)


def test_settle_without_a_move_does_nothing_and_after_one_lands_the_pins():
    rig = rigs.driver_rig(_head())
    drag, pins, targets, diag, results = _drag_to_random_pose(rig, 3, 6, moves=1)
    before = brig.read_controls(rig.controls)
    res = drag.settle()
    assert res.status == 0 and res.objective <= results[-1].objective
    np.testing.assert_allclose(res.points, _pin_points(rig.world_points(), pins), atol=1e-6 * diag)
    _assert_landed(rig, pins, targets, diag)
    drag.cancel()
    fresh = brig.RigDrag(rig.mesh, rig.controls)
    fresh.begin(pins)
    assert fresh.settle() is None
    fresh.cancel()
    assert np.abs(brig.read_controls(rig.controls) - before).max() > 0          # cancel put back the rest pose
