"""Direct manipulation in Blender: pins stored on a mesh, prior training from actions, drag solves to sliders.

Pins live in ``Object.shapespace.pins`` (:class:`SHAPESPACE_PG_pin`: three
vertex indices, three barycentric weights padded with zeros, a target in
shape-key space and a stationary flag).  Every write of pins, pin targets and
the active pin goes through the verbs here (:func:`add_pin`,
:func:`remove_pin`, :func:`clear_pins`, :func:`set_pin_target`,
:func:`set_active_pin`, :func:`undo_drag`); :func:`solve_pins` runs the core
solve (:func:`core.manipulation.solve_drag`) and writes the sliders.  An
interactive drag passes one :class:`core.manipulation.DragSession` to every
:func:`solve_pins` of the drag.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

import bpy
from mathutils.bvhtree import BVHTree

from ..core.blendshape import BlendshapeModel
from ..core.errors import ErrorCode
from ..core.manipulation import DragResult, DragSession, Pin, WeightPrior, pin_positions, solve_drag, train_prior
from ..core.result import ShapeSpaceError
from . import actions, meshes, shapekeys
from .arrays import read_float


def settings(obj):
    """The object's pin-and-drag settings (``Object.shapespace``)."""
    return obj.shapespace


def stored_pin(vertices: Sequence[int], weights: Sequence[float]) -> Pin:
    """The :class:`Pin` of stored (or operator) fields: 3 vertices and 3 weights, unused trailing weights 0."""
    count = 3 if weights[2] != 0.0 else (2 if weights[1] != 0.0 else 1)
    return Pin(tuple(vertices[:count]), tuple(weights[:count]))


def read_pins(obj):
    """Pins and their targets (shape-key space), ``(list of Pin, (k, 3) array, stationary (k,))``."""
    pins, targets, still = [], [], []
    for item in settings(obj).pins:
        pins.append(stored_pin(item.vertices, item.weights))
        targets.append(tuple(item.target))
        still.append(item.stationary)
    return pins, np.array(targets, dtype=np.float64).reshape(-1, 3), np.array(still, dtype=bool)


def add_pin(obj, pin: Pin, target=None, stationary: bool = False, model: BlendshapeModel | None = None) -> int:
    """Store a pin on the object, make it the active pin and return its index.

    ``target`` (3,) in shape-key space; ``None`` pins the point where it is now
    (at the current sliders of ``model``, read from ``obj`` when not given).
    """
    if target is None:
        model = model or shapekeys.read_blendshape_model(obj)
        target = pin_positions(model, [pin], model.values)[0]
    p = len(obj.data.vertices)
    if any(v < 0 or v >= p for v in pin.vertices):
        raise ShapeSpaceError(f"pin vertex out of range 0..{p - 1}", ErrorCode.PIN)
    item = settings(obj).pins.add()
    v = list(pin.vertices) + [pin.vertices[0]] * (3 - len(pin.vertices))
    w = list(pin.weights) + [0.0] * (3 - len(pin.weights))
    item.vertices, item.weights = v, w
    item.target = tuple(float(x) for x in target)
    item.stationary = stationary
    settings(obj).active_pin = len(settings(obj).pins) - 1
    return settings(obj).active_pin


def _pin_index(obj, index: int) -> int:
    if not 0 <= index < len(settings(obj).pins):
        raise ShapeSpaceError(f"there is no pin {index}", ErrorCode.RANGE)
    return index


def remove_pin(obj, index: int = -1) -> int:
    """Remove pin ``index`` (``-1``: the active pin); return the index removed."""
    st = settings(obj)
    index = _pin_index(obj, st.active_pin if index < 0 else index)
    st.pins.remove(index)
    st.active_pin = min(st.active_pin, len(st.pins) - 1)
    return index


def clear_pins(obj) -> None:
    """Remove every pin of the object."""
    settings(obj).pins.clear()
    settings(obj).active_pin = 0


def set_pin_target(obj, index: int, target) -> None:
    """Move pin ``index``'s target (3,), shape-key space."""
    settings(obj).pins[_pin_index(obj, index)].target = tuple(float(x) for x in target)


def set_active_pin(obj, index: int) -> None:
    """Make pin ``index`` the active one (the list's selection)."""
    settings(obj).active_pin = _pin_index(obj, index)


def pin_target(obj, index: int) -> tuple:
    """Pin ``index``'s target, shape-key space."""
    return tuple(settings(obj).pins[_pin_index(obj, index)].target)


def undo_drag(obj, before, index: int, created: bool, start_target) -> None:
    """Put back what a cancelled drag changed.

    ``before`` is ``(names, values)`` of the sliders when the drag started; the
    pin the drag created is removed, the pin it moved gets ``start_target`` back.
    """
    shapekeys.write_slider_values(obj, *before)
    st = settings(obj)
    if created:
        st.pins.remove(index)
        st.active_pin = max(0, len(st.pins) - 1)
    else:
        st.pins[index].target = start_target


def check_pins(obj) -> None:
    """Raise if stored pins refer to vertices the mesh no longer has."""
    p = len(obj.data.vertices)
    for j, item in enumerate(settings(obj).pins):
        if max(item.vertices) >= p:
            raise ShapeSpaceError(
                f"pin {j} refers to vertex {max(item.vertices)} but the mesh has {p}: clear the pins", ErrorCode.PIN)


def surface_pin(obj, depsgraph, origin_world, direction_world):
    """Ray-cast the evaluated surface (shape keys and deform modifiers applied).

    Returns ``(Pin, hit position in world space)`` or ``None`` when the ray misses.
    """
    ob_eval = obj.evaluated_get(depsgraph)
    mesh = ob_eval.to_mesh()
    try:
        if len(mesh.vertices) != len(obj.data.vertices):
            raise ShapeSpaceError("modifiers change this mesh's topology: pins need deform-only modifiers",
                                  ErrorCode.TOPOLOGY_MODIFIERS)
        inv = np.linalg.inv(meshes.world_matrix(obj))
        o = inv[:3, :3] @ np.asarray(origin_world, float) + inv[:3, 3]
        d = inv[:3, :3] @ np.asarray(direction_world, float)
        mesh.calc_loop_triangles()
        co = read_float(mesh.vertices, "co", 3).astype(np.float64)
        tri_v = np.empty(len(mesh.loop_triangles) * 3, dtype=np.int32)
        mesh.loop_triangles.foreach_get("vertices", tri_v)
        tri_v = tri_v.reshape(-1, 3)
        tree = BVHTree.FromPolygons(co.tolist(), tri_v.tolist(), all_triangles=True)
        loc, _normal, index, _dist = tree.ray_cast(o.tolist(), d.tolist())
        if loc is None:
            return None
        tri = tri_v[index]
        bary = _barycentric(np.array(loc), co[tri])
        pin = Pin(tuple(int(i) for i in tri), tuple(float(b) for b in bary))
        return pin, meshes.to_world(obj, np.array(loc)[None])[0]
    finally:
        ob_eval.to_mesh_clear()


def _barycentric(point, tri):
    a, b, c = tri
    v0, v1, v2 = b - a, c - a, point - a
    d00, d01, d11 = v0 @ v0, v0 @ v1, v1 @ v1
    d20, d21 = v2 @ v0, v2 @ v1
    den = d00 * d11 - d01 * d01
    if abs(den) < 1e-30:
        return np.array([1.0, 0.0, 0.0])
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    bary = np.clip(np.array([1.0 - v - w, v, w]), 0.0, 1.0)
    return bary / bary.sum()


def move_pin(obj, depsgraph, index: int, model: BlendshapeModel, weights, deformed_target) -> np.ndarray:
    """Set pin ``index``'s target from a point on the deformed surface (object space); return it in shape space."""
    pins, _, _ = read_pins(obj)
    target = deformed_to_shape_space(obj, depsgraph, pins[_pin_index(obj, index)], model, weights, deformed_target)
    set_pin_target(obj, index, target)
    return target


def deformed_to_shape_space(obj, depsgraph, pin: Pin, model, weights, deformed_target):
    """Map a target given on the deformed surface (object space) back to shape-key space.

    Uses Blender's crazy-space matrices (exact for linear deformers such as
    the Armature modifier at the current pose).
    """
    mods = [m for m in obj.modifiers if m.show_viewport]
    shape_pos = pin_positions(model, [pin], weights)[0]
    if not mods:
        return np.asarray(deformed_target, dtype=np.float64)
    deformed_now = _deformed_pin(obj, depsgraph, pin)
    delta = np.asarray(deformed_target, dtype=np.float64) - deformed_now
    obj.crazyspace_eval(depsgraph, bpy.context.scene)
    try:
        back = sum(b * np.array(obj.crazyspace_displacement_to_original(vertex_index=v, displacement=delta))
                   for v, b in zip(pin.vertices, pin.weights))
    finally:
        obj.crazyspace_eval_clear()
    return shape_pos + back


def _deformed_pin(obj, depsgraph, pin: Pin):
    co = meshes.evaluated_positions(obj, depsgraph).astype(np.float64)
    return sum(b * co[v] for v, b in zip(pin.vertices, pin.weights))


def deformed_pin_positions(obj, depsgraph) -> np.ndarray:
    """Current positions of the stored pins on the evaluated (deformed) surface, object space, (k, 3)."""
    pins, _, _ = read_pins(obj)
    if not pins:
        return np.zeros((0, 3))
    co = meshes.evaluated_positions(obj, depsgraph).astype(np.float64)
    return np.array([sum(b * co[v] for v, b in zip(p.vertices, p.weights)) for p in pins])


def prior_from_settings(obj, model: BlendshapeModel) -> WeightPrior | None:
    """Train the learned prior from the panel's action and frame range (None in other modes)."""
    st = settings(obj)
    if st.mode != "LEARNED":
        return None
    if st.prior_action is None:
        raise ShapeSpaceError("learned mode needs a prior action: pick one in the panel", ErrorCode.NO_PRIOR)
    curves = actions.shape_key_curves(obj, st.prior_action)
    known = [n for n in model.names if n in curves]
    if not known:
        raise ShapeSpaceError(f"action {st.prior_action.name!r} animates none of {obj.name!r}'s shape keys",
                              ErrorCode.PRIOR_CONSTANT)
    if st.prior_end < st.prior_start:
        raise ShapeSpaceError("the prior's frame range is empty (end before start)", ErrorCode.PRIOR_FRAMES)
    frames = np.arange(st.prior_start, st.prior_end + 1, dtype=np.float64)
    weights = actions.sample_shape_keys(obj, model.names, frames, action=st.prior_action)
    return train_prior(weights, model.names)


def solve_pins(obj, x0=None, model: BlendshapeModel | None = None, prior: WeightPrior | None = None, w0=None,
               session: DragSession | None = None) -> DragResult:
    """Solve for the sliders from the stored pins and the panel's settings, write them; return the DragResult.

    ``session`` is the interactive drag this solve belongs to (its pin rows,
    previous sliders and duals warm-start the solve); ``None`` for a one-off solve.
    """
    model = model or shapekeys.read_blendshape_model(obj)
    check_pins(obj)
    pins, targets, _ = read_pins(obj)
    st = settings(obj)
    if prior is None and st.mode == "LEARNED":
        prior = prior_from_settings(obj, model)
    w0 = model.values if w0 is None else w0
    result = solve_drag(model, pins, targets, w0, alpha=st.alpha, mu=st.mu, prior=prior,
                        prior_form="pca" if st.prior_form == "PCA" else "covariance", snap=st.snap, x0=x0,
                        session=session)
    shapekeys.write_slider_values(obj, model.names, result.weights)
    return result


def current_sliders(obj):
    """``(names, values)`` of the free sliders."""
    names = shapekeys.slider_names(obj)
    return names, shapekeys.read_slider_values(obj, names)


def key_changed(obj, before, after_values, frame, tol: float = 1e-6) -> int:
    """Key the sliders whose value changed from ``before`` (names, values); return how many."""
    names, values = before
    changed = [n for n, a, b in zip(names, values, after_values) if abs(a - b) > tol]
    return actions.key_sliders(obj, changed, frame)


def shape_to_deformed_targets(obj, depsgraph, pins, targets, deformed_now):
    """Targets (shape-key space) shown on the deformed surface: ``deformed + crazyspace(target − shape pos)``."""
    model = shapekeys.read_blendshape_model(obj)
    shape_now = pin_positions(model, pins, model.values)
    delta = np.asarray(targets, dtype=np.float64) - shape_now
    if not [m for m in obj.modifiers if m.show_viewport]:
        return deformed_now + delta
    obj.crazyspace_eval(depsgraph, bpy.context.scene)
    try:
        out = []
        for pin, d in zip(pins, delta):
            out.append(sum(b * np.array(obj.crazyspace_displacement_to_deformed(vertex_index=v, displacement=d))
                           for v, b in zip(pin.vertices, pin.weights)))
    finally:
        obj.crazyspace_eval_clear()
    return deformed_now + np.array(out)
