"""Mesh vertex positions: stored, evaluated, and world/local conversions."""
from __future__ import annotations

import numpy as np

from .arrays import matrix, read_float


def vertex_positions(mesh) -> np.ndarray:
    """Stored vertex positions of a ``bpy.types.Mesh``, float32 (p, 3)."""
    return read_float(mesh.vertices, "co", 3)


def evaluated_positions(obj, depsgraph) -> np.ndarray:
    """Object-space vertex positions after shape keys and modifiers, float32 (p, 3).

    Uses Blender's own evaluation (the depsgraph), brought up to date first
    (a no-op when nothing changed since the last evaluation).
    """
    depsgraph.update()
    ob_eval = obj.evaluated_get(depsgraph)
    mesh = ob_eval.to_mesh()
    try:
        return read_float(mesh.vertices, "co", 3)
    finally:
        ob_eval.to_mesh_clear()


def world_matrix(obj) -> np.ndarray:
    """``obj.matrix_world`` as float64 (4, 4)."""
    return matrix(obj.matrix_world)


def to_world(obj, points) -> np.ndarray:
    """Object-space points (p, 3) → world space, float64."""
    m = world_matrix(obj)
    pts = np.asarray(points, dtype=np.float64)
    return pts @ m[:3, :3].T + m[:3, 3]


def to_local(obj, points) -> np.ndarray:
    """World-space points (p, 3) → the object's space, float64."""
    m = np.linalg.inv(world_matrix(obj))
    pts = np.asarray(points, dtype=np.float64)
    return pts @ m[:3, :3].T + m[:3, 3]


def vertex_groups(obj):
    """Every vertex's group memberships in Blender's stored order.

    Returns
    -------
    group_index : ndarray of int, shape (p, k)
        Index into ``obj.vertex_groups`` (``-1`` padding).
    weight : ndarray of float32, shape (p, k)
    names : list of str
        ``obj.vertex_groups`` names by index.

    Notes
    -----
    Blender exposes no bulk accessor for deform weights, so this walks the
    vertices once; call it when a rig is set up, never per frame.
    """
    mesh = obj.data
    names = [g.name for g in obj.vertex_groups]
    counts = np.fromiter((len(v.groups) for v in mesh.vertices), dtype=np.int64, count=len(mesh.vertices))
    k = int(counts.max()) if counts.size else 0
    p = len(mesh.vertices)
    gi = np.full((p, max(k, 1)), -1, dtype=np.int64)
    gw = np.zeros((p, max(k, 1)), dtype=np.float32)
    if k:
        flat_g = [g.group for v in mesh.vertices for g in v.groups]
        flat_w = [g.weight for v in mesh.vertices for g in v.groups]
        rows = np.repeat(np.arange(p), counts)
        cols = np.arange(len(flat_g)) - np.repeat(np.cumsum(counts) - counts, counts)
        gi[rows, cols] = flat_g
        gw[rows, cols] = flat_w
    return gi, gw, names


def group_weight_vector(obj, group_name: str, cache=None) -> np.ndarray:
    """Per-vertex weight of one vertex group (0 where unassigned), float64 (p,)."""
    gi, gw, names = cache if cache is not None else vertex_groups(obj)
    if group_name not in names:
        return None
    idx = names.index(group_name)
    return np.where(gi == idx, gw, 0.0).sum(axis=1).astype(np.float64)


def triangles(mesh) -> np.ndarray:
    """The mesh's triangles from Blender's own tessellation (``loop_triangles``), int (f, 3)."""
    mesh.calc_loop_triangles()
    tris = np.empty(len(mesh.loop_triangles) * 3, dtype=np.int32)
    mesh.loop_triangles.foreach_get("vertices", tris)
    return tris.reshape(-1, 3).astype(np.int64)
