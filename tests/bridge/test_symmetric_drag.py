"""Symmetric pin-and-drag and mirrored pins (issue #13) on the FBHead head, checked through Blender's own
evaluation (depsgraph) and save/reload.

The head's rig is made exactly symmetric first (every Right key rewritten as the mirror of its Left key and every
middle key symmetrised, through the stored mirror map), so a symmetric drag has a symmetric answer.
"""
import os

import numpy as np
import pytest

from blender_support import bpy, evaluated, import_file
from shapespace.bridge import manipulation, meshes, shapekeys, symmetry
from shapespace.core import symmetry as core_sym
from shapespace.core.manipulation import Pin, pin_positions
from support import ASSETS

WEIGHTS = (0.6, 0.3, 0.1)


def _activate(ob):
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    bpy.context.view_layer.objects.active = ob
    ob.select_set(True)


def _fbhead(build_map=True, symmetric_rig=True):
    import_file(os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend"))
    ob = bpy.data.objects["FBHead"]
    ob.data.shape_keys.animation_data_clear()
    for kb in ob.data.shape_keys.key_blocks[1:]:
        kb.value = 0.0
    _activate(ob)
    if build_map:
        assert bpy.ops.shapespace.build_mirror_map("EXEC_DEFAULT") == {"FINISHED"}
    if symmetric_rig:
        mmap = symmetry.load_map(ob)
        blocks = ob.data.shape_keys.key_blocks
        for kb in list(blocks)[1:]:
            other = core_sym.counterpart_name(kb.name)
            if other is None:
                symmetry.update_mirrored(ob, kb.name, mmap)               # a middle key: symmetrised
            elif kb.name.endswith("Left") and other in blocks:
                symmetry.update_mirrored(ob, kb.name, mmap)               # its Right key: the mirror
    st = ob.shapespace
    st.mode = "DIRECT"
    st.alpha, st.mu = 1e-4, 1e-6                  # reachable targets are reached (α, μ pull back very little)
    return ob


def _diag(ob):
    rest = symmetry.rest_positions(ob)
    return float(np.linalg.norm(np.ptp(rest, axis=0)))


def _transform(ob):
    ob.location = (0.3, -0.2, 0.1)
    ob.rotation_euler = (0.4, 0.1, -0.3)
    ob.scale = (1.3, 0.8, 1.1)
    bpy.context.view_layer.update()


def _triangle_at(ob, vertex):
    me = ob.data
    me.calc_loop_triangles()
    tris = np.empty(len(me.loop_triangles) * 3, np.int32)
    me.loop_triangles.foreach_get("vertices", tris)
    tris = tris.reshape(-1, 3)
    row = tris[np.flatnonzero((tris == vertex).any(axis=1))[0]]
    row = [vertex] + [int(v) for v in row if v != vertex]
    return tuple(int(v) for v in row)


def _blink_triangle(ob, model):
    """A triangle on the left upper eyelid (the vertex EyeBlinkLeft moves most) that has a distinct mirror."""
    mmap = symmetry.load_map(ob)
    d = np.linalg.norm(model.deltas[model.index("EyeBlinkLeft")], axis=1)
    v = int(np.argmax(d))
    assert mmap.mirror[v] != v
    return _triangle_at(ob, v)


def _goal(model, names_values):
    w = np.zeros(model.n_targets)
    for n, x in names_values.items():
        w[model.index(n)] = x
    return w


def _targets(ob):
    return manipulation.read_pin_state(ob).targets


def _links(ob):
    return [p.mirror_of for p in ob.shapespace.pins]


def _reflect(point, mmap):
    out = np.array(point, dtype=np.float64)
    out[..., mmap.axis] = 2 * mmap.offset - out[..., mmap.axis]
    return out


def _surface_points(ob):
    """Where Blender's depsgraph puts the stored pins (object space; no deform modifiers: shape-key space)."""
    ev = evaluated(ob)
    state = manipulation.read_pin_state(ob)
    return np.einsum("kc,kcx->kx", state.weights, ev[state.vertices])


def _drag(ob, index, goal_local, steps=6):
    """A scripted viewport drag of pin ``index`` to ``goal_local`` (given as world points, as the mouse does)."""
    drag = manipulation.Drag(ob)
    drag.grab(ob, index)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    start = _surface_points(ob)[index]
    for t in np.linspace(0, 1, steps + 1)[1:]:
        world = meshes.to_world(ob, (start + t * (np.asarray(goal_local) - start))[None])[0]
        drag.move(ob, depsgraph, world)
    return drag


def _sliders(ob):
    names = shapekeys.slider_names(ob)
    return dict(zip(names, shapekeys.read_slider_values(ob, names)))


def test_symmetric_drag_moves_a_pin_and_its_mirror_and_gives_symmetric_sliders(registered):
    ob = _fbhead()
    _transform(ob)                                   # world drags go through a rotated, non-uniformly scaled object
    mmap = symmetry.load_map(ob)
    model = shapekeys.read_blendshape_model(ob)
    tri = _blink_triangle(ob, model)
    ob.shapespace.symmetric = True
    assert bpy.ops.shapespace.add_pin(vertices=tri, weights=WEIGHTS) == {"FINISHED"}
    pins = ob.shapespace.pins
    assert len(pins) == 2 and _links(ob) == [1, 0]
    assert tuple(pins[1].vertices) == tuple(int(mmap.mirror[v]) for v in tri)
    np.testing.assert_allclose(tuple(pins[1].weights), WEIGHTS, atol=1e-7)
    assert ob.shapespace.active_pin == 0

    goal_w = _goal(model, {"EyeBlinkLeft": 0.7, "EyeBlinkRight": 0.7})
    goal = pin_positions(model, [Pin(tri, WEIGHTS)], goal_w)[0]
    start = _surface_points(ob)[0]
    _drag(ob, 0, goal)
    diag = _diag(ob)
    targets = _targets(ob)
    np.testing.assert_allclose(targets[0], goal, atol=1e-6 * diag)
    # the mirror pin's target is the reflection of the dragged target (object space, across the map's plane)
    np.testing.assert_allclose(targets[1], _reflect(targets[0], mmap), atol=1e-6 * diag)
    # both pins sit on their targets where Blender's depsgraph puts the surface
    on = _surface_points(ob)
    reach = np.linalg.norm(goal - start)
    assert reach > 1e-3 * diag
    assert np.linalg.norm(on - targets, axis=1).max() < 0.005 * reach, (on, targets)
    # a symmetric rig gives symmetric sliders
    w = _sliders(ob)
    assert w["EyeBlinkLeft"] > 0.5
    for name, value in w.items():
        other = core_sym.counterpart_name(name)
        if other in w:
            assert abs(value - w[other]) < 1e-4, (name, value, other, w[other])

    # the same drag without Symmetric moves one side only (the mirror pin stays where it was)
    ob.shapespace.symmetric = False
    names = list(w)
    shapekeys.write_slider_values(ob, names, np.zeros(len(names)))
    manipulation.set_pin_target(ob, 1, pin_positions(model, [manipulation.read_pins(ob)[0][1]],
                                                     np.zeros(model.n_targets))[0])
    manipulation.set_pin_target(ob, 0, start)
    _drag(ob, 0, goal)
    w = _sliders(ob)
    assert w["EyeBlinkLeft"] > 0.5 and w["EyeBlinkRight"] < 0.05


def test_world_space_solve_and_centre_pin(registered):
    ob = _fbhead()
    _transform(ob)
    mmap = symmetry.load_map(ob)
    model = shapekeys.read_blendshape_model(ob)
    ob.shapespace.symmetric = True
    # a pin on the centre line (the chin vertex JawOpen moves most) is its own mirror: one pin, linked to itself
    centre = np.flatnonzero(mmap.centre)
    d = np.linalg.norm(model.deltas[model.index("JawOpen")], axis=1)
    chin = int(centre[np.argmax(d[centre])])
    assert bpy.ops.shapespace.add_pin(vertices=(chin, 0, 0), weights=(1, 0, 0)) == {"FINISHED"}
    assert len(ob.shapespace.pins) == 1 and _links(ob) == [0]
    # Solve Pins with a WORLD target beside the plane: the target lands on the plane, the sliders are symmetric
    goal = pin_positions(model, [Pin.at_vertex(chin)], _goal(model, {"JawOpen": 0.5, "JawLeft": 0.3}))[0]
    assert abs(goal[mmap.axis] - mmap.offset) > 1e-3 * _diag(ob)
    world = meshes.to_world(ob, goal[None])[0]
    assert bpy.ops.shapespace.solve_pins(pin=0, target=world, space="WORLD") == {"FINISHED"}
    t = _targets(ob)[0]
    assert abs(t[mmap.axis] - mmap.offset) < 1e-6 * _diag(ob)
    np.testing.assert_allclose(np.delete(t, mmap.axis), np.delete(goal, mmap.axis), atol=1e-5 * _diag(ob))
    w = _sliders(ob)
    assert w["JawOpen"] > 0.3 and abs(w["JawLeft"] - w["JawRight"]) < 1e-4
    # a WORLD solve of a mirrored pair: the mirror target is the object-space reflection of the converted target
    tri = _blink_triangle(ob, model)
    assert bpy.ops.shapespace.add_pin(vertices=tri, weights=WEIGHTS) == {"FINISHED"}
    assert _links(ob) == [0, 2, 1]
    goal = pin_positions(model, [Pin(tri, WEIGHTS)], _goal(model, {"EyeBlinkLeft": 0.5, "EyeBlinkRight": 0.5}))[0]
    world = meshes.to_world(ob, goal[None])[0]
    start = _surface_points(ob)[1]
    assert bpy.ops.shapespace.solve_pins(pin=1, target=world, space="WORLD") == {"FINISHED"}
    targets = _targets(ob)
    np.testing.assert_allclose(targets[1], goal, atol=1e-5 * _diag(ob))
    np.testing.assert_allclose(targets[2], _reflect(targets[1], mmap), atol=1e-6 * _diag(ob))
    on = _surface_points(ob)
    assert np.linalg.norm(on[1:] - targets[1:], axis=1).max() < 0.005 * np.linalg.norm(goal - start)


def test_cancel_restores_both_pins_and_removes_a_created_pair(registered):
    ob = _fbhead()
    model = shapekeys.read_blendshape_model(ob)
    ob.shapespace.symmetric = True
    tri = _blink_triangle(ob, model)
    # an existing pair, dragged and cancelled: both targets and the sliders come back
    manipulation.add_pin(ob, Pin(tri, WEIGHTS), model=model)
    before_targets = _targets(ob).copy()
    before_sliders = _sliders(ob)
    goal = pin_positions(model, [Pin(tri, WEIGHTS)], _goal(model, {"EyeBlinkLeft": 0.8, "EyeBlinkRight": 0.8}))[0]
    drag = _drag(ob, 0, goal)
    assert _sliders(ob)["EyeBlinkRight"] > 0.5
    assert np.abs(_targets(ob) - before_targets).max() > 1e-4
    drag.cancel(ob)
    np.testing.assert_array_equal(_targets(ob), before_targets)
    assert _sliders(ob) == pytest.approx(before_sliders, abs=1e-7)
    np.testing.assert_allclose(evaluated(ob), symmetry.rest_positions(ob), atol=1e-6 * _diag(ob))
    # a pair created by the drag (what the Pin tool does on a click): cancel removes both, the old pair stays
    brow = int(np.argmax(np.linalg.norm(model.deltas[model.index("BrowOuterUpLeft")], axis=1)))
    drag = manipulation.Drag(ob)
    index = manipulation.add_pin(ob, Pin.at_vertex(brow), None, model=drag.model)
    assert index == 2 and len(ob.shapespace.pins) == 4 and _links(ob) == [1, 0, 3, 2]
    drag.grab(ob, index, created=True)
    up = pin_positions(model, [Pin.at_vertex(brow)], _goal(model, {"BrowOuterUpLeft": 0.6,
                                                                   "BrowOuterUpRight": 0.6}))[0]
    drag.move(ob, bpy.context.evaluated_depsgraph_get(), meshes.to_world(ob, up[None])[0])
    assert _sliders(ob)["BrowOuterUpRight"] > 0.3
    drag.cancel(ob)
    assert len(ob.shapespace.pins) == 2 and _links(ob) == [1, 0]
    np.testing.assert_array_equal(_targets(ob), before_targets)
    assert _sliders(ob) == pytest.approx(before_sliders, abs=1e-7)


def test_links_survive_save_and_reload_and_removal_renumbers(registered, tmp_path):
    ob = _fbhead()
    model = shapekeys.read_blendshape_model(ob)
    manipulation.add_pin(ob, Pin.at_vertex(5), model=model)              # Symmetric off: no link (−1)
    assert _links(ob) == [-1]
    ob.shapespace.symmetric = True
    tri = _blink_triangle(ob, model)
    manipulation.add_pin(ob, Pin(tri, WEIGHTS), model=model)
    assert _links(ob) == [-1, 2, 1]
    path = str(tmp_path / "sym_pins.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.open_mainfile(filepath=path)
    ob = bpy.data.objects["FBHead"]
    _activate(ob)
    assert ob.shapespace.symmetric and _links(ob) == [-1, 2, 1]
    # the reloaded pair still drags together
    mmap = symmetry.load_map(ob)
    goal = pin_positions(model, [Pin(tri, WEIGHTS)], _goal(model, {"EyeBlinkLeft": 0.5, "EyeBlinkRight": 0.5}))[0]
    _drag(ob, 1, goal)
    targets = _targets(ob)
    np.testing.assert_allclose(targets[2], _reflect(targets[1], mmap), atol=1e-6 * _diag(ob))
    w = _sliders(ob)
    assert w["EyeBlinkLeft"] > 0.3 and abs(w["EyeBlinkLeft"] - w["EyeBlinkRight"]) < 1e-4
    # removing the unlinked pin renumbers the pair's links; removing one of the pair unlinks the other
    assert bpy.ops.shapespace.remove_pin(index=0) == {"FINISHED"}
    assert _links(ob) == [1, 0]
    assert bpy.ops.shapespace.remove_pin(index=1) == {"FINISHED"}
    assert _links(ob) == [-1]


def test_symmetric_pin_refused_without_a_fresh_map_or_on_an_unmapped_vertex(registered):
    ob = _fbhead(build_map=False, symmetric_rig=False)
    ob.shapespace.symmetric = True
    with pytest.raises(RuntimeError, match="no mirror map"):
        bpy.ops.shapespace.add_pin(vertices=(10, 0, 0))
    assert len(ob.shapespace.pins) == 0
    # a vertex without a mirror in the stored map
    mmap = symmetry.build_map(ob, "POSITION")
    mirror = mmap.mirror.copy()
    v = int(np.flatnonzero(mirror != np.arange(len(mirror)))[0])
    mirror[[v, mirror[v]]] = -1
    symmetry.store_map(ob, core_sym.MirrorMap(mirror, axis=mmap.axis, offset=mmap.offset, method="position"))
    with pytest.raises(RuntimeError, match=f"vertex {v}, which has no mirror"):
        bpy.ops.shapespace.add_pin(vertices=(v, 0, 0))
    assert len(ob.shapespace.pins) == 0
    # Mirror Pins refuses the same pin, writing nothing
    ob.shapespace.symmetric = False
    assert bpy.ops.shapespace.add_pin(vertices=(v, 0, 0)) == {"FINISHED"}
    with pytest.raises(RuntimeError, match="which has no mirror"):
        bpy.ops.shapespace.mirror_pins()
    assert len(ob.shapespace.pins) == 1 and _links(ob) == [-1]
    # a stale map (a vertex deleted since it was built)
    assert bpy.ops.shapespace.build_mirror_map("EXEC_DEFAULT") == {"FINISHED"}
    bpy.ops.shapespace.clear_pins()
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.select_all(action="DESELECT")
    bpy.ops.object.mode_set(mode="OBJECT")
    ob.data.vertices[0].select = True
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.delete(type="VERT")
    bpy.ops.object.mode_set(mode="OBJECT")
    ob.shapespace.symmetric = True
    with pytest.raises(RuntimeError, match="stale"):
        bpy.ops.shapespace.add_pin(vertices=(10, 0, 0))
    assert len(ob.shapespace.pins) == 0


def test_mirror_pins_operator(registered):
    ob = _fbhead()
    mmap = symmetry.load_map(ob)
    model = shapekeys.read_blendshape_model(ob)
    tri = _blink_triangle(ob, model)
    brow = int(np.argmax(np.linalg.norm(model.deltas[model.index("BrowDownLeft")], axis=1)))
    chin = int(np.flatnonzero(mmap.centre)[0])
    twin = tuple(int(mmap.mirror[v]) for v in tri)
    ob.shapespace.symmetric = False
    for verts, weights in ((tri, WEIGHTS), ((brow, 0, 0), (1, 0, 0)), ((chin, 0, 0), (1, 0, 0)), (twin, WEIGHTS)):
        assert bpy.ops.shapespace.add_pin(vertices=verts, weights=weights) == {"FINISHED"}
    ob.shapespace.pins[1].stationary = True
    # give the brow pin a target away from where it is, to see it reflected
    manipulation.set_pin_target(ob, 1, _targets(ob)[1] + np.array([0.01, 0.02, 0.03]))
    assert bpy.ops.shapespace.mirror_pins() == {"FINISHED"}
    pins = ob.shapespace.pins
    # the triangle and its already pinned mirror are linked, the brow pin gets a new mirror, the chin is centre
    assert _links(ob) == [3, 4, 2, 0, 1]
    assert tuple(pins[4].vertices)[0] == int(mmap.mirror[brow]) and pins[4].stationary
    targets = _targets(ob)
    np.testing.assert_allclose(targets[4], _reflect(targets[1], mmap), atol=1e-6 * _diag(ob))
    # a second run has nothing left to do
    assert bpy.ops.shapespace.mirror_pins() == {"FINISHED"}
    assert len(pins) == 5 and _links(ob) == [3, 4, 2, 0, 1]
    # a symmetric drag of the mirrored brow pin moves the original along
    ob.shapespace.symmetric = True
    goal = targets[4] + np.array([0.0, 0.0, 0.005])
    _drag(ob, 4, goal, steps=2)
    targets = _targets(ob)
    np.testing.assert_allclose(targets[1], _reflect(targets[4], mmap), atol=1e-6 * _diag(ob))


def test_pins_of_a_0_1_0_file_load_unlinked(registered):
    path = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "data", "shapespace_0_1_0.blend")
    assert bpy.ops.wm.open_mainfile(filepath=path) == {"FINISHED"}
    ob = bpy.data.objects["Pinned"]
    _activate(ob)
    assert len(ob.shapespace.pins) and set(_links(ob)) == {-1} and not ob.shapespace.symmetric
    # Mirror Pins without a mirror map is refused with the reason, nothing changes
    with pytest.raises(RuntimeError, match="no mirror map"):
        bpy.ops.shapespace.mirror_pins()
    assert set(_links(ob)) == {-1}
