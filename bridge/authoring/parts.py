"""The facial parts of a Transfer Shapes target in Blender (issue #22 §1): the panel's *Parts* list and the parts
their rig moves by itself.

A part is a connected piece of the target mesh or of one of its part objects (:mod:`bridge.part_objects`), named
by its object and its lowest vertex index there (``Mesh_0`` vertex 0), so the list survives edits elsewhere.
The list is kept on the target (``Object.shapespace_authoring.parts``): each row holds the kind the user chose
(*Auto*: what the proposal finds, :mod:`core.authoring.parts`) and shows the kind the last *Find Parts* or
transfer used and why.  A row whose part changed (its vertex is no longer the lowest of a part: the mesh was
edited) is refused by name when the user had set its kind; an *Auto* row is simply refreshed.

A part object without shape keys of its own that its rig moves by itself is kept still unless the user sets
its kind: shape keys would move it a second time.  Its rig moves it when, below the target's own parents, its
transform or a parent's is animated (an action or NLA strip, muted or not, whose transform curves change),
driven or constrained, when it hangs from another bone than the target does, or when an armature that does not
deform the target deforms it — Face Cap's eyes turn by the rotation of their ``grp_eye*`` parents.
"""
from __future__ import annotations

from dataclasses import dataclass

import bpy
import numpy as np

from ...core.authoring.job import TargetMesh
from ...core.authoring.mesh import triangle_parts
from ...core.authoring.parts import USER_KINDS, PartPlan, propose_parts
from ...core.errors import ErrorCode
from ...core.jobs import BackgroundJob
from ...core.progress import notify, scaled
from ...core.result import ShapeSpaceError
from .. import actions, part_objects
from .reading import read_target, target_signature, with_part_objects

__all__ = ["AUTO", "TRANSFORM_PATHS", "moved_by_rig", "part_kinds", "find_parts", "show_parts", "part_vertices",
           "select_part", "part_owner", "rig_kinds", "FindPartsPlan", "FindPartsOutcome", "read_find_parts",
           "compute_find_parts", "write_find_parts", "start_find_parts_job", "finish_find_parts_job"]

#: The list's kind meaning "as the proposal finds".
AUTO = "auto"
#: Data paths of an object's transform: animation, drivers or constraints on them move the object.
TRANSFORM_PATHS = ("location", "rotation_euler", "rotation_quaternion", "rotation_axis_angle", "scale",
                   "delta_location", "delta_rotation_euler", "delta_rotation_quaternion", "delta_scale")
#: Relative difference of a part's size (:func:`_firsts`) beyond which a row no longer names it.
SIZE_TOL = 1e-4
#: A transform curve whose keyed values differ by less than this moves nothing.
STILL_CURVE = 1e-6


def _curves_of(ob) -> list:
    """F-Curves that animate ``ob``: its active action's and its NLA strips' (each through its own slot), muted
    tracks included (importers such as glTF's put each take on a muted track; the rig still plays it)."""
    ad = ob.animation_data
    if ad is None:
        return []
    strips = [strip for track in ad.nla_tracks for strip in track.strips]
    return actions.active_fcurves(ob) + [fc for strip in strips for fc in actions.strip_fcurves(strip, ob)]


def _moving_curve(fc) -> bool:
    if fc.mute or fc.data_path not in TRANSFORM_PATHS:
        return False
    values = np.empty(len(fc.keyframe_points) * 2, dtype=np.float64)
    fc.keyframe_points.foreach_get("co", values)
    return bool(values.size and np.ptp(values[1::2]) > STILL_CURVE) or len(fc.modifiers) > 0


def _holds_to(con, shared: set, own_bone) -> bool:
    """True when constraint ``con`` ties its owner to the face itself: its target is the face or one of its
    parents (an armature: the bone the face hangs from, or none named)."""
    target = getattr(con, "target", None)
    if target is None or target.name not in shared:
        return False
    bone = getattr(con, "subtarget", "")
    return not bone or (own_bone is not None and (target.name, bone) == own_bone)


def _transform_moved(node, shared: set = frozenset(), own_bone=None) -> str:
    """Why ``node``'s own transform moves (animated, driven, constrained other than to the face), '' when it
    does not."""
    for fc in _curves_of(node):
        if _moving_curve(fc):
            return f"the {fc.data_path} of {node.name!r} is animated"
    ad = node.animation_data
    for fc in (ad.drivers if ad is not None else ()):
        if fc.data_path in TRANSFORM_PATHS and not fc.mute:
            return f"the {fc.data_path} of {node.name!r} is driven"
    for con in node.constraints:
        if con.enabled and con.influence > 0 and not _holds_to(con, shared, own_bone):
            return f"{node.name!r} has a {con.type.replace('_', ' ').title()} constraint"
    return ""


def moved_by_rig(ob, target) -> str:
    """Why the rig moves part object ``ob`` relative to ``target`` by itself ('' when it does not).

    Parameters
    ----------
    ob, target : bpy.types.Object

    Returns
    -------
    str
        A sentence naming the object and what moves it: an armature deforming ``ob`` but not ``target``; below
        the target's own parents, an animated, driven or constrained transform of ``ob`` or a parent, or a
        parent bone other than the target's.  '' for an object with shape keys of its own: its rig moves it
        with shape keys, so it gets the transferred ones (Ready Player Me's eyes and teeth; their armature
        deforms the whole avatar).
    """
    key = ob.data.shape_keys
    if key is not None and len(key.key_blocks) > 1:
        return ""
    face = {mod.object.name for mod in target.modifiers if mod.type == "ARMATURE" and mod.object is not None}
    for mod in ob.modifiers:
        if mod.type == "ARMATURE" and mod.object is not None and mod.show_viewport and mod.object.name not in face:
            return f"{ob.name!r} is deformed by the armature {mod.object.name!r}"
    shared, node = set(), target
    while node is not None:
        shared.add(node.name)
        node = node.parent
    own_bone = (target.parent.name, target.parent_bone) if target.parent_type == "BONE" and target.parent else None
    node = ob
    while node is not None and node.name not in shared:
        why = _transform_moved(node, shared, own_bone)
        if why:
            return why
        if node.parent_type == "BONE" and node.parent is not None and (node.parent.name, node.parent_bone) != own_bone:
            return f"{node.name!r} hangs from the bone {node.parent_bone!r} of {node.parent.name!r}"
        node = node.parent
    return ""


def part_owner(tgt: TargetMesh, vertex: int) -> tuple:
    """(object name, its own vertex index) of a row of the joined target; the name is '' for the target itself
    (the list survives renaming it)."""
    for p in tgt.objects:
        if p.start <= vertex < p.start + p.count:
            return p.name, vertex - p.start
    return "", vertex


def _joined(tgt: TargetMesh, name: str, index: int) -> int:
    """Row of the joined target of ``name``'s vertex ``index`` ('': the target's own; −1: not in this transfer,
    or out of range)."""
    if not name:
        own = tgt.own if tgt.own >= 0 else len(tgt.neutral)
        return index if 0 <= index < own else -1
    for p in tgt.objects:
        if p.name == name:
            return p.start + index if 0 <= index < p.count else -1
    return -1


def _firsts(tgt: TargetMesh) -> tuple:
    """(part label per joined vertex, lowest vertex of each part label, each part's vertex count, each part's
    size: the summed length of its triangles' edges — unchanged by moving or turning a part object, changed by
    editing the part)."""
    lab, _ = triangle_parts(len(tgt.neutral), tgt.triangles)
    on = np.flatnonzero(lab >= 0)
    count = int(lab.max()) + 1 if on.size else 0
    first = np.full(count, -1, dtype=np.int64)
    labels, at = np.unique(lab[on], return_index=True)
    first[labels] = on[at]
    T = np.asarray(tgt.triangles, dtype=np.int64)
    V = np.asarray(tgt.neutral, dtype=np.float64)
    edges = np.linalg.norm(V[T] - V[np.roll(T, 1, axis=1)], axis=2).sum(axis=1)
    size = np.bincount(lab[T[:, 0]], weights=edges, minlength=count) if count else np.zeros(0)
    return lab, first, np.bincount(lab[on], minlength=count), size


def _fits(vertices: int, size: float, count: int, now: float) -> bool:
    """A row's stored vertex count and size still describe a part of ``count`` vertices and size ``now``."""
    return vertices == count and abs(size - now) <= SIZE_TOL * max(now, 1e-30)


def _same_part(row, parts: tuple, v) -> bool:
    """Row ``row`` still names the part at joined vertex ``v`` (``parts``: :func:`_firsts`): the lowest vertex
    of a part of the same vertex count and size (a part whose lowest index another part took over after an edit
    is not the same)."""
    lab, first, counts, size = parts
    if v < 0 or lab[v] <= 0 or first[lab[v]] != v:
        return False
    return _fits(row.vertices, row.size, int(counts[lab[v]]), float(size[lab[v]]))


def part_kinds(target, tgt: TargetMesh, strict: bool = True) -> dict:
    """The parts whose kind is not left to the proposal: ``{joined vertex: (kind, reason)}``
    (:attr:`core.authoring.job.TransferPlan.part_kinds`).

    Rows of the panel's list the user set, then every part of a part object its rig moves (:func:`moved_by_rig`,
    kept ``still``) that no row sets.  ``strict=False`` (*Find Parts*) passes over a set row whose part is gone
    (it stays listed, shown as gone, for the user to set back to *Auto*).

    Raises
    ------
    ShapeSpaceError
        A set row whose part no longer exists (object not in this transfer, vertex out of range or no longer
        the lowest vertex of a part: the mesh was edited), or whose kind is unknown — naming the row.
    """
    found = _firsts(tgt)
    out = {}
    for row in target.shapespace_authoring.parts:
        if row.kind == AUTO:
            continue
        where = f"part {row.object or target.name!r} vertex {row.vertex} (set to {row.kind!r})"
        if row.kind not in USER_KINDS:
            raise ShapeSpaceError(f"{where}: not one of {', '.join(USER_KINDS)}", ErrorCode.INVALID)
        v = _joined(tgt, row.object, row.vertex)
        if not _same_part(row, found, v):
            if not strict:
                continue
            raise ShapeSpaceError(f"{where} is no longer a part of this transfer (the mesh or its Part Objects "
                                  f"changed): Find Parts again, or set the row to Auto", ErrorCode.STALE_PART)
        out[v] = (row.kind, "set by the user")
    spans = [(bpy.data.objects[p.name], p.start, p.count) for p in tgt.objects]
    for v, kind in rig_kinds(target, spans, found[0]).items():
        out.setdefault(v, kind)
    return out


def rig_kinds(target, spans, labels: np.ndarray) -> dict:
    """Every part of a part object its rig moves (:func:`moved_by_rig`), kept still: ``{its lowest joined vertex:
    ("still", reason)}``.

    Parameters
    ----------
    target : bpy.types.Object
    spans : sequence of (bpy.types.Object, int, int)
        Each part object with its first row and vertex count in the joined target.
    labels : ndarray of int (n,)
        Part per joined vertex (:func:`core.authoring.mesh.triangle_parts`).
    """
    out = {}
    for ob, start, count in spans:
        why = moved_by_rig(ob, target)
        if not why:
            continue
        span = labels[start:start + count]
        inside = np.flatnonzero(span > 0)
        _, at = np.unique(span[inside], return_index=True)
        for i in inside[at]:
            out[start + int(i)] = ("still", f"moved by its rig: {why}")
    return out


def show_parts(target, tgt: TargetMesh, summary: list) -> int:
    """Fill the panel's list from a part plan's summary (:meth:`core.authoring.parts.PartPlan.summary`, rows of
    the joined target ``tgt``): each part's object, vertex, vertex count and size, the kind used and why.  A kind
    the user set stays on its row while the row names the same part (:func:`_same_part`); a set row that no
    longer does is kept, shown as gone, for the transfer to refuse by name; *Auto* rows of parts gone are
    dropped.  Returns the number of parts listed."""
    lab, _, counts, size = _firsts(tgt)
    items = target.shapespace_authoring.parts
    old = [(row.object, row.vertex, row.kind, row.vertices, row.size) for row in items]
    used, rows = set(), []
    for s in (s for s in summary if s["kind"] != "skin" and s.get("first", -1) >= 0):
        name, index = part_owner(tgt, s["first"])
        q = lab[s["first"]]
        kind = AUTO
        for i, (o, v, k, n, z) in enumerate(old):
            if i not in used and k != AUTO and (o, v) == (name, index) and _fits(n, z, int(counts[q]), size[q]):
                kind = k
                used.add(i)
                break
        rows.append((name, index, int(s["vertices"]), float(size[q]), kind, s["kind"], s["reason"],
                     bool(s.get("unsure", False))))
    gone = [(o, v, n, z, k, "", "not this part any more (the mesh or its Part Objects changed): set it to Auto",
             False) for i, (o, v, k, n, z) in enumerate(old) if k != AUTO and i not in used]
    items.clear()
    for values in rows + gone:
        row = items.add()
        row.object, row.vertex, row.vertices, row.size, row.kind, row.used, row.reason, row.unsure = values
    st = target.shapespace_authoring
    st.active_part = max(0, min(st.active_part, len(items) - 1))
    return len(rows)


@dataclass(frozen=True)
class FindPartsPlan:
    """What :func:`read_find_parts` read (main thread) for the proposal to compute from."""

    target: str
    parts: tuple            #: the part objects' names
    tgt: TargetMesh         #: the target joined with its part objects
    signature: tuple        #: :func:`.reading.target_signature` when read
    members: tuple          #: the names of the meshes in the target's Part Objects collection when read


@dataclass(frozen=True)
class FindPartsOutcome:
    """The proposal (:func:`compute_find_parts`), not yet shown."""

    plan: FindPartsPlan
    proposal: PartPlan


def read_find_parts(target, parts=()) -> FindPartsPlan:
    """Step 1 of :func:`find_parts` (main thread): read the target and its part objects; writes nothing.
    Refused: what reading the target refuses (not a mesh, Edit Mode, no faces, non-finite), a part object
    refused."""
    parts = list(parts)
    tgt = with_part_objects(target, None, read_target(target), parts)
    return FindPartsPlan(target.name, tuple(p.name for p in parts), tgt, target_signature(target, parts),
                         _members(target))


def _members(target) -> tuple:
    return tuple(ob.name for ob in part_objects.meshes_of(target.shapespace_authoring.parts_collection, target))


def compute_find_parts(plan: FindPartsPlan, progress=None) -> FindPartsOutcome:
    """Step 2 (any thread, no Blender data): the connected parts and the kind proposed for each from their
    shapes alone (a transfer refines jaw against skull with the transferred ``jawOpen``)."""
    tgt = plan.tgt
    lab, _ = triangle_parts(len(tgt.neutral), tgt.triangles)
    proposal = propose_parts(tgt.neutral, tgt.triangles, lab, progress=scaled(progress, 0.0, 0.99))
    notify(progress, 1.0)
    return FindPartsOutcome(plan, proposal)


def write_find_parts(outcome: FindPartsOutcome) -> int:
    """Step 3 (main thread): apply the kinds the user set and the rig's (:func:`part_kinds`, read now) and fill
    the list (:func:`show_parts`); returns the number of parts listed.  Refused, with the list unchanged, when
    the target or its part objects changed since :func:`read_find_parts`, or a row is set to a kind it does not
    know."""
    plan = outcome.plan
    target = bpy.data.objects.get(plan.target)
    parts = [bpy.data.objects.get(name) for name in plan.parts]
    if (target is None or target.type != "MESH" or any(p is None for p in parts)
            or target_signature(target, parts) != plan.signature or _members(target) != plan.members):
        raise ShapeSpaceError(f"{plan.target!r} or its Part Objects changed while Find Parts computed: the list "
                              f"was not changed; Find Parts again", ErrorCode.RIG_CHANGED)
    proposal = outcome.proposal
    kinds = part_kinds(target, plan.tgt, strict=False)
    if kinds:
        proposal = proposal.with_vertex_kinds(kinds)
    return show_parts(target, plan.tgt, proposal.summary())


def start_find_parts_job(plan: FindPartsPlan) -> BackgroundJob:
    """Start :func:`compute_find_parts` of ``plan`` in a worker thread (a modal operator polls the job and
    cancels it on Esc); :func:`finish_find_parts_job` shows its outcome once it is done."""
    return BackgroundJob(lambda progress: compute_find_parts(plan, progress), name="ShapeSpace find parts").start()


def finish_find_parts_job(job: BackgroundJob) -> int:
    """Show a finished job's parts (main thread); re-raises what stopped the job (``Cancelled`` on Esc): the
    list is unchanged then."""
    return write_find_parts(job.result())


def find_parts(target, parts=()) -> int:
    """*Find Parts*: propose the kind of every part of ``target`` and its part objects ``parts`` from their
    shapes alone, apply the kinds the user set and the rig's (:func:`part_kinds`), and fill the list
    (:func:`show_parts`): :func:`read_find_parts` → :func:`compute_find_parts` → :func:`write_find_parts`.
    Returns the number of parts listed.

    Raises
    ------
    ShapeSpaceError
        What reading the target refuses (not a mesh, Edit Mode, no faces, non-finite), a part object refused,
        a row set to a kind it does not know.
    """
    return write_find_parts(compute_find_parts(read_find_parts(target, parts)))


def part_vertices(target, index: int, parts=()) -> tuple:
    """(object, its vertex indices) of row ``index`` of the list: what *Select Part* selects."""
    items = target.shapespace_authoring.parts
    if not 0 <= index < len(items):
        raise ShapeSpaceError(f"no part {index} ({len(items)} listed)", ErrorCode.RANGE)
    row = items[index]
    tgt = with_part_objects(target, None, read_target(target), list(parts))
    found = _firsts(tgt)
    lab = found[0]
    v = _joined(tgt, row.object, row.vertex)
    if not _same_part(row, found, v):
        raise ShapeSpaceError(f"part {row.object or target.name!r} vertex {row.vertex} is no longer a part of the "
                              f"mesh: Find Parts again", ErrorCode.STALE_PART)
    rows = np.flatnonzero(lab == lab[v])
    start = v - row.vertex
    return (bpy.data.objects[row.object] if row.object else target), rows - start


def select_part(target, index: int, parts=()) -> tuple:
    """*Select Part*: select row ``index``'s vertices on its mesh (all others deselected; seen in Edit Mode).
    Returns (object name, vertex count).  Refused: a row out of range or stale, its mesh in Edit Mode."""
    ob, verts = part_vertices(target, index, parts)
    if ob.mode == "EDIT":
        raise ShapeSpaceError(f"{ob.name!r} is in Edit Mode: leave it to select a part", ErrorCode.MODE)
    mask = np.zeros(len(ob.data.vertices), dtype=bool)
    mask[verts] = True
    ob.data.vertices.foreach_set("select", mask)
    ob.data.edges.foreach_set("select", mask[_edge_vertices(ob.data)].all(axis=1))
    ob.data.polygons.foreach_set("select", np.zeros(len(ob.data.polygons), dtype=bool))
    ob.data.update()
    return ob.name, int(verts.size)


def _edge_vertices(mesh) -> np.ndarray:
    ev = np.empty(len(mesh.edges) * 2, dtype=np.int32)
    mesh.edges.foreach_get("vertices", ev)
    return ev.reshape(-1, 2)
