"""The evaluated surface a drag happens on: world ↔ shape-key space, crazy-space maps, pin positions, picking.

Pins store their targets in shape-key space (the mesh's own undeformed
coordinates); the artist sees and drags them on the evaluated surface, after
the shape keys, the deform modifiers and the object's transform.  Between
the two sit

- the object's world matrix (parents included): :func:`world_to_local`;
- the deform modifiers, per vertex an affine map ``deformed = A s + c`` of
  the vertex's shape-key position ``s`` — exact for the Armature modifier at
  a fixed pose (linear or dual-quaternion skinning, any number of armatures):
  :class:`DeformMap`, built from Blender's crazy-space matrices
  (``Object.crazyspace_eval``) for just the pinned vertices.

A :class:`DeformMap` depends on the pose, not on the sliders or the key
coordinates, so it is cached (in the object's :class:`~.cache.RigEntry`) and
rebuilt only when :func:`deform_state` changes — the object's and the
armatures' transforms, the pose and rest bones and their names, any modifier
setting — when the deform weights of a vertex it covers change, or when a new
pin needs a vertex it lacks.  A stack with any other deform modifier (lattice, smooth,
…) is not affine in the shape-key positions: its map is rebuilt at every
use, at the sliders of that moment (as Blender's crazy space is).

Pin positions on the surface are read from the evaluated mesh itself
(``Object.evaluated_get(depsgraph).data``), a few vertices at a time: what
Blender shows, never a copy of the whole mesh.
"""
from __future__ import annotations

from dataclasses import dataclass

import bpy
import numpy as np

from ...core.blendshape import BlendshapeModel
from ...core.errors import ErrorCode
from ...core.manipulation import Pin, pin_positions
from ...core.manipulation.geometry import ray_hit
from ...core.result import ShapeSpaceError
from .. import meshes, shapekeys
from .cache import RIGS

__all__ = ["DeformMap", "deform_state", "deform_map", "vertex_weights", "evaluated_mesh", "evaluated_vertices",
           "world_to_local", "inverse_world", "finite_point", "triangles", "surface_pin"]

_AXES = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
_PLAIN_TYPES = {"BOOLEAN", "INT", "FLOAT", "STRING", "ENUM"}


def finite_point(point, what: str) -> np.ndarray:
    """``point`` as a float64 (3,) vector, refused when it is not 3 finite numbers (``what`` names it)."""
    try:
        out = np.asarray(point, dtype=np.float64).reshape(3)
    except (TypeError, ValueError):
        raise ShapeSpaceError(f"{what} must be 3 numbers, got {point!r}", ErrorCode.SHAPE) from None
    if not np.isfinite(out).all():
        raise ShapeSpaceError(f"{what} is not finite: {tuple(out.tolist())}", ErrorCode.NON_FINITE)
    return out


def inverse_world(obj) -> np.ndarray:
    """The inverse of ``obj``'s world matrix (4, 4); refused when it has a zero or non-finite scale.

    An affine matrix: its 3 × 3 part is inverted by its adjugate (cross products of the rows), without a
    LAPACK call — this runs at every mouse move.
    """
    m = meshes.world_matrix(obj)
    lin = m[:3, :3]
    size = float(np.abs(lin).max()) if np.isfinite(m).all() else 0.0
    r0, r1, r2 = lin
    cols = np.array([[r1[1] * r2[2] - r1[2] * r2[1], r1[2] * r2[0] - r1[0] * r2[2], r1[0] * r2[1] - r1[1] * r2[0]],
                     [r2[1] * r0[2] - r2[2] * r0[1], r2[2] * r0[0] - r2[0] * r0[2], r2[0] * r0[1] - r2[1] * r0[0]],
                     [r0[1] * r1[2] - r0[2] * r1[1], r0[2] * r1[0] - r0[0] * r1[2], r0[0] * r1[1] - r0[1] * r1[0]]])
    det = float(r0 @ cols[0]) if size else 0.0
    if size == 0.0 or abs(det) <= 1e-12 * size ** 3:
        raise ShapeSpaceError(f"object {obj.name!r} has a zero or non-finite scale (its world matrix cannot be "
                              "inverted): a point in the scene has no position on it", ErrorCode.SINGULAR)
    inv = np.eye(4)
    inv[:3, :3] = cols.T / det
    inv[:3, 3] = -inv[:3, :3] @ m[:3, 3]
    return inv


def world_to_local(obj, points) -> np.ndarray:
    """World-space points (k, 3) in ``obj``'s space; refused when its world matrix cannot be inverted."""
    inv = inverse_world(obj)
    return np.asarray(points, dtype=np.float64) @ inv[:3, :3].T + inv[:3, 3]


# ---------------------------------------------------------------------------- the evaluated mesh
def evaluated_mesh(obj, depsgraph):
    """``obj``'s evaluated mesh (shape keys and modifiers applied; Blender's own, not a copy).

    The depsgraph is brought up to date first (a no-op when nothing changed).  Refused when modifiers change
    the vertex count: pins index the mesh's vertices.
    """
    depsgraph.update()
    mesh = obj.evaluated_get(depsgraph).data
    if len(mesh.vertices) != len(obj.data.vertices):
        raise ShapeSpaceError("modifiers change this mesh's topology: pins need deform-only modifiers",
                              ErrorCode.TOPOLOGY_MODIFIERS)
    return mesh


def evaluated_vertices(obj, depsgraph, vertices) -> np.ndarray:
    """Evaluated object-space positions (m, 3) of the given vertex indices, as Blender shows them."""
    verts = evaluated_mesh(obj, depsgraph).vertices
    return np.array([verts[int(v)].co for v in vertices], dtype=np.float64).reshape(-1, 3)


# ---------------------------------------------------------------------------- crazy space
class _ModifierProperties:
    """Per modifier type, the names of its plain, array and pointer properties (read once from its RNA)."""

    def __init__(self):
        self._by_type: dict = {}

    def of(self, mod) -> tuple:
        found = self._by_type.get(mod.type)
        if found is None:
            plain, arrays, pointers = [], [], []
            for prop in mod.bl_rna.properties:
                if prop.identifier == "rna_type":
                    continue
                if prop.type in _PLAIN_TYPES:
                    (arrays if getattr(prop, "is_array", False) else plain).append(prop.identifier)
                elif prop.type == "POINTER":
                    pointers.append(prop.identifier)
            found = self._by_type[mod.type] = (tuple(plain), tuple(arrays), tuple(pointers))
        return found


#: The property names of each modifier type (RNA definitions: they never change within a session).
_MODIFIER_PROPERTIES = _ModifierProperties()


def _settings(mod) -> tuple:
    """A modifier's settings as plain values (pointers by ``session_uid``)."""
    plain, arrays, pointers = _MODIFIER_PROPERTIES.of(mod)
    return (tuple(getattr(mod, n) for n in plain), tuple(tuple(getattr(mod, n)) for n in arrays),
            tuple(getattr(getattr(mod, n), "session_uid", None) for n in pointers))


def _armature_pose(arm) -> tuple:
    """What an armature's deformation depends on: its transform, pose and rest matrices, deform flags."""
    bones = arm.pose.bones
    pose = np.empty(len(bones) * 16, dtype=np.float32)
    bones.foreach_get("matrix", pose)
    rest = np.empty(len(arm.data.bones) * 16, dtype=np.float32)
    arm.data.bones.foreach_get("matrix_local", rest)
    deform = np.empty(len(arm.data.bones), dtype=bool)
    arm.data.bones.foreach_get("use_deform", deform)
    return (arm.session_uid, meshes.world_matrix(arm).tobytes(), pose.tobytes(), rest.tobytes(), deform.tobytes(),
            arm.data.pose_position, tuple(b.name for b in arm.data.bones))


def vertex_weights(obj, vertices) -> dict:
    """Deform weights of the given vertices: ``{vertex: ((group name, weight), ...)}`` (a few RNA reads each)."""
    mverts, groups = obj.data.vertices, obj.vertex_groups
    return {int(v): tuple((groups[g.group].name if g.group < len(groups) else g.group, g.weight)
                          for g in mverts[int(v)].groups) for v in vertices}


def deform_state(obj) -> tuple | None:
    """``(fingerprint, affine)`` of ``obj``'s deform modifiers, or ``None`` when none is shown in the viewport.

    ``affine`` is true when every modifier is an Armature modifier: the map from shape-key space to the
    surface is then affine per vertex and does not depend on the sliders.
    """
    mods = [m for m in obj.modifiers if m.show_viewport]
    if not mods:
        return None
    parts, affine = [meshes.world_matrix(obj).tobytes()], True
    for mod in mods:
        parts.append((mod.type, _settings(mod)))
        if mod.type == "ARMATURE":
            arm = mod.object
            if arm is not None and arm.type == "ARMATURE":
                parts.append(_armature_pose(arm))
        else:
            affine = False
    return tuple(parts), affine


@dataclass
class DeformMap:
    """Per-vertex affine maps from shape-key space to the deformed surface, ``deformed = A s + c``.

    Attributes
    ----------
    state : tuple
        :func:`deform_state` fingerprint it was built at.
    affine : bool
        Valid for any sliders (Armature modifiers only); otherwise only at the sliders it was built at.
    verts : ndarray of int, shape (m,)
        The vertices it covers, sorted.
    A, A_inv : ndarray, shape (m, 3, 3)
        Blender's crazy-space matrices: a shape-key displacement → the deformed displacement, and back.
    weights : dict
        :func:`vertex_weights` of ``verts`` when it was built.
    c : ndarray, shape (m, 3), or None
        The affine part (needs the model's positions; computed when asked for).
    """

    state: tuple
    affine: bool
    verts: np.ndarray
    A: np.ndarray
    A_inv: np.ndarray
    weights: dict
    c: np.ndarray | None = None

    def rows(self, vertices) -> np.ndarray:
        """Row of each vertex in this map."""
        return np.searchsorted(self.verts, np.asarray(vertices, dtype=np.int64))

    def covers(self, vertices, weights: dict) -> bool:
        """It has these vertices, at these deform weights (:func:`vertex_weights`)."""
        return all(self.weights.get(v) == w for v, w in weights.items())


def _crazyspace(obj, depsgraph, verts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Crazy-space matrices ``A`` and ``A⁻¹`` (m, 3, 3) of the given vertices at the current evaluation."""
    A = np.empty((len(verts), 3, 3))
    A_inv = np.empty((len(verts), 3, 3))
    obj.crazyspace_eval(depsgraph, bpy.context.scene)
    try:
        for i, v in enumerate(verts.tolist()):
            for axis, e in enumerate(_AXES):
                A[i, :, axis] = obj.crazyspace_displacement_to_deformed(vertex_index=v, displacement=e)
                A_inv[i, :, axis] = obj.crazyspace_displacement_to_original(vertex_index=v, displacement=e)
    finally:
        obj.crazyspace_eval_clear()
    return A, A_inv


def deform_map(obj, depsgraph, vertices, model: BlendshapeModel | None = None,
               offsets: bool = False) -> DeformMap | None:
    """The :class:`DeformMap` of ``obj`` covering ``vertices``; ``None`` when no deform modifier is shown.

    Reuses the one cached on the object's rig entry while :func:`deform_state` is unchanged (and the
    stack is affine); ``offsets`` also fills ``c``, reading the shape-key positions from ``model`` (default:
    the cached model) at the sliders as they are now.
    """
    found = deform_state(obj)
    if found is None:
        return None
    state, affine = found
    entry = RIGS.peek(obj)
    need = np.unique(np.asarray(vertices, dtype=np.int64).ravel())
    weights = vertex_weights(obj, need)
    dmap = entry.derived.get("deform") if entry is not None else None
    if dmap is None or not affine or dmap.state != state or not dmap.covers(need, weights):
        if dmap is not None and affine and dmap.state == state:
            keep = [v for v in dmap.verts.tolist() if v not in weights]
            weights.update(vertex_weights(obj, keep))
            need = np.union1d(need, keep).astype(np.int64)
        A, A_inv = _crazyspace(obj, depsgraph, need)
        dmap = DeformMap(state, affine, need, A, A_inv, weights)
        if entry is not None and affine:
            entry.derived["deform"] = dmap
    if offsets and dmap.c is None:
        model = model if model is not None else RIGS.model(obj)
        weights = shapekeys.read_slider_values(obj, model.names)
        shape = pin_positions(model, [Pin.at_vertex(int(v)) for v in dmap.verts], weights)
        deformed = evaluated_vertices(obj, depsgraph, dmap.verts)
        dmap.c = deformed - np.einsum("mij,mj->mi", dmap.A, shape)
    return dmap


# ---------------------------------------------------------------------------- picking
def triangles(mesh) -> np.ndarray:
    """Vertex indices of the mesh's triangles (t, 3) (one bulk read)."""
    tris = mesh.loop_triangles
    out = np.empty(len(tris) * 3, dtype=np.int32)
    tris.foreach_get("vertices", out)
    return out.reshape(-1, 3)


def surface_pin(obj, depsgraph, origin_world, direction_world):
    """Ray-cast the evaluated surface (shape keys and deform modifiers applied).

    Returns ``(Pin, hit position in world space)`` or ``None`` when the ray misses.
    """
    mesh = evaluated_mesh(obj, depsgraph)
    inv = inverse_world(obj)
    origin = inv[:3, :3] @ np.asarray(origin_world, float) + inv[:3, 3]
    direction = inv[:3, :3] @ np.asarray(direction_world, float)
    co = meshes.vertex_positions(mesh).astype(np.float64)
    tris = triangles(mesh)
    hit = ray_hit(origin, direction, co, tris)
    if hit is None:
        return None
    index, bary, point = hit
    pin = Pin(tuple(int(i) for i in tris[index]), tuple(float(b) for b in bary))
    return pin, meshes.to_world(obj, point[None])[0]
