"""Pins on a mesh, prior training from actions, and applying drag solves to the sliders."""
from __future__ import annotations

import numpy as np

import bpy
from mathutils.bvhtree import BVHTree

from ..core.manipulation.solve import Pin, pin_positions, solve_drag, train_prior
from ..core.result import ShapeSpaceError
from . import actions, meshes, shapekeys
from .arrays import read_float


def settings(obj):
    return obj.shapespace


def read_pins(obj):
    """Pins and their targets (shape-key space), ``(list of Pin, (k, 3) array, stationary (k,))``."""
    pins, targets, still = [], [], []
    for item in settings(obj).pins:
        count = 3 if item.weights[2] != 0.0 else (2 if item.weights[1] != 0.0 else 1)
        pins.append(Pin(tuple(item.vertices[:count]), tuple(item.weights[:count])))
        targets.append(tuple(item.target))
        still.append(item.stationary)
    return pins, np.array(targets, dtype=np.float64).reshape(-1, 3), np.array(still, dtype=bool)


def add_pin(obj, pin: Pin, target, stationary: bool = False) -> int:
    """Store a pin on the object; return its index."""
    p = len(obj.data.vertices)
    if any(v < 0 or v >= p for v in pin.vertices):
        raise ShapeSpaceError(f"pin vertex out of range 0..{p - 1}", "pin")
    item = settings(obj).pins.add()
    v = list(pin.vertices) + [pin.vertices[0]] * (3 - len(pin.vertices))
    w = list(pin.weights) + [0.0] * (3 - len(pin.weights))
    item.vertices, item.weights = v, w
    item.target = tuple(float(x) for x in target)
    item.stationary = stationary
    settings(obj).active_pin = len(settings(obj).pins) - 1
    return settings(obj).active_pin


def check_pins(obj) -> None:
    """Raise if stored pins refer to vertices the mesh no longer has."""
    p = len(obj.data.vertices)
    for j, item in enumerate(settings(obj).pins):
        if max(item.vertices) >= p:
            raise ShapeSpaceError(
                f"pin {j} refers to vertex {max(item.vertices)} but the mesh has {p}: clear the pins", "pin")


def surface_pin(obj, depsgraph, origin_world, direction_world):
    """Ray-cast the evaluated surface (shape keys and deform modifiers applied).

    Returns ``(Pin, hit position in world space)`` or ``None`` when the ray misses.
    """
    ob_eval = obj.evaluated_get(depsgraph)
    mesh = ob_eval.to_mesh()
    try:
        if len(mesh.vertices) != len(obj.data.vertices):
            raise ShapeSpaceError("modifiers change this mesh's topology: pins need deform-only modifiers",
                                  "topology_modifiers")
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


def prior_from_settings(obj, model):
    """Train the learned prior from the panel's action and frame range (None in other modes)."""
    st = settings(obj)
    if st.mode != "LEARNED":
        return None
    if st.prior_action is None:
        raise ShapeSpaceError("learned mode needs a prior action: pick one in the panel", "no_prior")
    curves = actions.shape_key_curves(obj, st.prior_action)
    known = [n for n in model.names if n in curves]
    if not known:
        raise ShapeSpaceError(f"action {st.prior_action.name!r} animates none of {obj.name!r}'s shape keys",
                              "prior_constant")
    if st.prior_end < st.prior_start:
        raise ShapeSpaceError("the prior's frame range is empty (end before start)", "prior_frames")
    frames = np.arange(st.prior_start, st.prior_end + 1, dtype=np.float64)
    weights = actions.sample_shape_keys(obj, model.names, frames, action=st.prior_action)
    return train_prior(weights, model.names)


def solve_pins(obj, x0=None, model=None, prior=None, w0=None, warm=None):
    """Solve for the sliders from the stored pins and write them; return the DragResult.

    ``warm`` is the previous mouse-move's result (its weights, duals and pin rows are reused).
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
                        warm=warm)
    shapekeys.write_slider_values(obj, model.names, result.weights)
    return result


def current_sliders(obj):
    """``(names, values)`` of the free sliders."""
    names = actions.slider_names(obj)
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
