"""Rig authoring by model transfer (thesis 3.4.1): a source rig's shape keys onto any other head.

The only module that touches Blender for *Transfer Shapes*.  It reads the source rig (neutral, triangles,
every key's delta, slider ranges, vertex-group masks, driven in-betweens and combinations — see
:mod:`bridge.driven`) and the target mesh (any topology), keeps the landmark pairs per target object
(a versioned blob, ``Object['shapespace_landmarks']``), shows the registration as a preview object, and writes the
transferred shapes onto the target in one step after everything is computed: validate → compute → write,
and on any failure the file is as before.  The three steps are separate (:func:`read_transfer` on the main
thread, :func:`compute_transfer` on any thread — the operator runs it in a :class:`core.jobs.BackgroundJob`,
cancellable — and :func:`write_transfer` on the main thread).  The maths is :mod:`core.authoring`.

Deltas are transferred *unmasked*; a source key's vertex-group mask becomes a vertex group of the target
(weights mapped through the correspondence) named on the new key, so Blender applies it exactly as on the
source.  In-betweens and combination shapes are transferred as full sculpts and rebuilt on the target with
:func:`bridge.driven.add_inbetween` / :func:`~bridge.driven.add_combination` (native drivers: they play
back without the add-on).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import bpy
import numpy as np

from ..core import authoring as core
from ..core.authoring import contacts as core_contacts
from ..core.authoring import named as core_named
from ..core.authoring import parts as core_parts
from ..core.authoring import quality as core_quality
from ..core.errors import ErrorCode
from ..core.jobs import BackgroundJob
from ..core.progress import notify, scaled
from ..core.result import Result, ShapeSpaceError, Status, to_jsonable
from ..core import blobs
from ..core.validate import ABSURD_COORDINATE, coordinates
from . import driven, named_landmarks, part_objects, shapekeys, storage
from .arrays import read_float, write_float
from .meshes import triangles, vertex_groups

__all__ = ["MIN_LANDMARKS", "PREVIEW_PROP", "LANDMARKS_PROP", "NAMINGS", "EXISTING", "SourceRig", "TargetMesh",
           "TransferReport", "read_source_rig", "read_target", "landmark_pairs", "landmark_count", "landmark_list",
           "add_landmark", "remove_landmark", "set_landmarks", "clear_landmarks", "propose_landmarks",
           "register_source", "show_preview", "clear_preview", "preview_object", "transfer_shapes",
           "selected_vertex", "append_object", "remove_appended", "TransferPlan", "TransferOutcome", "read_transfer",
           "compute_transfer", "write_transfer", "start_transfer_job", "finish_transfer_job"]

MIN_LANDMARKS = 5
PREVIEW_PROP = "shapespace_registration_preview"
NAMINGS = ("source", "arkit", "suffix", "pascal")
EXISTING = ("refuse", "skip", "overwrite")
_TMP = "__shapespace_transfer_tmp"
_WEIGHT_STEP = 1e-4        # mapped mask weights are written rounded to this (one vertex-group call per value)


# ------------------------------------------------------------------ reading
@dataclass
class SourceRig:
    """A source rig as arrays: every non-reference key, unmasked deltas, and what to rebuild on the target."""

    name: str
    neutral: np.ndarray                 # (p, 3) reference-key positions, object space
    triangles: np.ndarray               # (f, 3) int
    names: list                         # every key to transfer, in key order
    deltas: np.ndarray                  # (n, p, 3) key − its relative key, unmasked
    slider_min: np.ndarray              # (n,)
    slider_max: np.ndarray              # (n,)
    mute: np.ndarray                    # (n,) bool
    groups: dict                        # key name → vertex-group name (masks)
    group_weights: dict                 # vertex-group name → (p,) weights
    inbetweens: dict                    # key name → {"primary", "at"}
    combinations: dict                  # key name → {"inputs"}

    def full_sculpts(self) -> np.ndarray:
        """Each key's full shape at its slider = 1: a driven key's correction plus what its drivers add
        (``t·S_P`` for an in-between of ``P`` at ``t``, ``ΣS_inputs`` for a combination), (n, p, 3)."""
        index = {n: i for i, n in enumerate(self.names)}
        out = self.deltas.copy()
        for name, v in self.inbetweens.items():
            out[index[name]] += float(v["at"]) * self.deltas[index[v["primary"]]]
        for name, v in self.combinations.items():
            out[index[name]] += sum(self.deltas[index[i]] for i in v["inputs"])
        return out


@dataclass
class TargetMesh:
    name: str
    neutral: np.ndarray                 # (q, 3) reference key (or mesh) positions, object space
    triangles: np.ndarray               # (u, 3) int
    keys: list                          # existing shape-key names (reference first), [] without keys
    parts: int                          # connected parts through triangles (loose vertices in none)
    own: int = -1                       # the target object's own vertices (the first rows); -1: all
    objects: list = field(default_factory=list)     # part objects appended after them (bridge.part_objects)


def _mesh_object(obj, role: str):
    if obj is None:
        raise ShapeSpaceError(f"choose the {role} mesh", ErrorCode.NO_OBJECT)
    if obj.type != "MESH":
        raise ShapeSpaceError(f"the {role} {obj.name!r} is a {obj.type.lower()}, not a mesh", ErrorCode.NOT_MESH)
    if obj.mode == "EDIT":
        raise ShapeSpaceError(f"the {role} {obj.name!r} is in Edit Mode: leave Edit Mode first", ErrorCode.MODE)
    if len(obj.data.vertices) == 0:
        raise ShapeSpaceError(f"the {role} {obj.name!r} has no vertices", ErrorCode.EMPTY)
    return obj


def _neutral(obj) -> np.ndarray:
    key = obj.data.shape_keys
    if key is not None and len(key.key_blocks):
        return read_float(key.reference_key.points, "co", 3).astype(np.float64)
    return read_float(obj.data.vertices, "co", 3).astype(np.float64)


def _finite(obj, role: str, name: str, co: np.ndarray) -> None:
    coordinates(co, f"{role} {obj.name!r}: {name}", ABSURD_COORDINATE, fix="fix the mesh")


def read_source_rig(obj) -> SourceRig:
    """Read a rig to transfer from (refuses one without targets, NaN, or damaged keys, naming the culprit)."""
    _mesh_object(obj, "source rig")
    errors = [i for i in shapekeys.check_shape_keys(obj) if i.severity == "error"]
    if errors:
        raise ShapeSpaceError(f"source rig: {errors[0].message}", errors[0].code)
    key = obj.data.shape_keys
    ref = key.reference_key
    blocks = [kb for kb in key.key_blocks if kb != ref]
    coords = {kb.name: read_float(kb.points, "co", 3).astype(np.float64) for kb in key.key_blocks}
    shapekeys.check_coordinates(obj, coords, ref.name, "source rig")
    meta = driven.prune(key)
    names = [kb.name for kb in blocks]
    deltas = np.stack([coords[kb.name] - coords[(kb.relative_key or ref).name] if kb.relative_key != kb
                       else np.zeros_like(coords[ref.name]) for kb in blocks])
    used_groups = {kb.name: kb.vertex_group for kb in blocks if kb.vertex_group}
    groups, weights = {}, {}
    if used_groups:
        cache = vertex_groups(obj)
        for key_name, group in used_groups.items():
            if group in cache[2]:            # Blender ignores a mask naming a missing group: so do we
                groups[key_name] = group
                idx = cache[2].index(group)
                weights[group] = np.where(cache[0] == idx, cache[1], 0.0).sum(axis=1).astype(np.float64)
    lo = np.array([kb.slider_min for kb in blocks], dtype=np.float64)
    hi = np.array([kb.slider_max for kb in blocks], dtype=np.float64)
    if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
        bad = next(kb.name for kb in blocks if not (np.isfinite(kb.slider_min) and np.isfinite(kb.slider_max)))
        raise ShapeSpaceError(f"source rig {obj.name!r}: shape key {bad!r} has a non-finite slider range",
                              ErrorCode.NON_FINITE)
    return SourceRig(name=obj.name, neutral=coords[ref.name], triangles=triangles(obj.data), names=names,
                     deltas=deltas, slider_min=lo, slider_max=hi,
                     mute=np.array([kb.mute for kb in blocks], dtype=bool), groups=groups, group_weights=weights,
                     inbetweens=meta["inbetweens"], combinations=meta["combinations"])


def read_target(obj) -> TargetMesh:
    """Read the mesh to transfer onto: its neutral (reference key, else the mesh), triangles, keys, parts."""
    _mesh_object(obj, "target")
    key = obj.data.shape_keys
    if key is not None:
        errors = [i for i in shapekeys.check_shape_keys(obj) if i.severity == "error" and i.code != "no_targets"]
        if errors and errors[0].code != "no_shape_keys":
            raise ShapeSpaceError(f"target: {errors[0].message}", errors[0].code)
    neutral = _neutral(obj)
    _finite(obj, "target", "the neutral", neutral)
    tris = triangles(obj.data)
    if not len(tris):
        raise ShapeSpaceError(f"the target {obj.name!r} has no faces: transfer needs a surface", ErrorCode.EMPTY)
    keys = [kb.name for kb in key.key_blocks] if key is not None else []
    parts = len(core.triangle_parts(len(neutral), tris)[1])
    return TargetMesh(name=obj.name, neutral=neutral, triangles=tris, keys=keys, parts=parts)


# ------------------------------------------------------------------ landmarks (per target object)
#: ``{"pairs": [[source vertex, target vertex], …], "source_vertices": int, "target_vertices": int}`` — the
#: vertex counts the pairs were placed on (a topology change makes them stale).
LANDMARKS_PROP = "shapespace_landmarks"
LANDMARKS_SCHEMA = blobs.LANDMARK_PAIRS.schema


def _stored(target) -> dict:
    data = storage.read_id_blob(target, LANDMARKS_PROP, LANDMARKS_SCHEMA)
    pairs = data.get("pairs", [])
    ok = all(isinstance(p, list) and len(p) == 2 and all(isinstance(v, int) and not isinstance(v, bool) and v >= 0
                                                         for v in p) for p in pairs)
    if not ok:
        raise ShapeSpaceError(f"damaged ShapeSpace data in {storage.where(target, LANDMARKS_PROP)}: every pair "
                              f"needs two vertex indices (Clear Landmarks and place them again)",
                              ErrorCode.CORRUPT_METADATA)
    return {"pairs": pairs, "source_vertices": int(data.get("source_vertices", 0)),
            "target_vertices": int(data.get("target_vertices", 0))}


def _store_pairs(target, source, pairs: list) -> None:
    storage.write_id_blob(target, LANDMARKS_PROP, LANDMARKS_SCHEMA,
                          {"pairs": [[int(a), int(b)] for a, b in pairs],
                           "source_vertices": len(source.data.vertices),
                           "target_vertices": len(target.data.vertices)})


def landmark_count(target) -> tuple:
    """``(number of stored pairs, problem)``: ``problem`` is '' or one line (damaged data); never raises."""
    if target is None or LANDMARKS_PROP not in target:
        return 0, ""
    try:
        return len(_stored(target)["pairs"]), ""
    except ShapeSpaceError as exc:
        return 0, str(exc)


def landmark_list(target) -> list:
    """The stored pairs as ``[(source vertex, target vertex), …]`` ([] when none or damaged); for panels."""
    try:
        return [tuple(p) for p in _stored(target)["pairs"]] if LANDMARKS_PROP in target else []
    except ShapeSpaceError:
        return []


def selected_vertex(obj):
    """The single selected vertex of a mesh (object-mode data), or None."""
    sel = np.zeros(len(obj.data.vertices), dtype=bool)
    obj.data.vertices.foreach_get("select", sel)
    idx = np.flatnonzero(sel)
    return int(idx[0]) if idx.size == 1 else None


def landmark_pairs(target, source=None, check: bool = True) -> tuple:
    """The stored pairs ``(source vertices, target vertices)``, int arrays (m,).

    With ``check``: refuses pairs that became stale (either mesh's vertex count changed since they were
    placed) or point past the end of a mesh, naming the mesh.
    """
    data = _stored(target)
    pairs = np.asarray(data["pairs"], dtype=np.int64).reshape(-1, 2)
    src, dst = pairs[:, 0].copy(), pairs[:, 1].copy()
    if check and len(pairs):
        if data["target_vertices"] != len(target.data.vertices):
            raise ShapeSpaceError(f"the landmarks of {target.name!r} were placed when it had "
                                  f"{data['target_vertices']} vertices, now {len(target.data.vertices)}: clear and "
                                  f"place them again", ErrorCode.STALE_LANDMARKS)
        if source is not None and data["source_vertices"] != len(source.data.vertices):
            raise ShapeSpaceError(f"the landmarks of {target.name!r} were placed on a source with "
                                  f"{data['source_vertices']} vertices; {source.name!r} has "
                                  f"{len(source.data.vertices)}: clear and place them again",
                                  ErrorCode.STALE_LANDMARKS)
        for idx, ob, role in ((src, source, "the source rig"), (dst, target, "the target")):
            if ob is not None and idx.max() >= len(ob.data.vertices):
                _check_vertex(ob, int(idx.max()), role)
    return src, dst


def _check_vertex(obj, index: int, role: str) -> int:
    if not 0 <= int(index) < len(obj.data.vertices):
        raise ShapeSpaceError(f"{role} {obj.name!r} has no vertex {index}", ErrorCode.RANGE)
    return int(index)


def add_landmark(target, source, source_vertex: int, target_vertex: int) -> int:
    """Add the pair (replacing a pair already using either vertex); returns the number of pairs."""
    _mesh_object(source, "source rig")
    _mesh_object(target, "target")
    a = _check_vertex(source, source_vertex, "the source rig")
    b = _check_vertex(target, target_vertex, "the target")
    src, dst = landmark_pairs(target, source)
    keep = [(x, y) for x, y in zip(src.tolist(), dst.tolist()) if x != a and y != b]
    _store_pairs(target, source, keep + [(a, b)])
    return len(keep) + 1


def remove_landmark(target, index: int) -> int:
    """Remove pair ``index`` (−1: the last one); returns the number left."""
    data = _stored(target)
    pairs = data["pairs"]
    if not -len(pairs) <= index < len(pairs) or not pairs:
        raise ShapeSpaceError(f"{target.name!r} has no landmark pair {index} ({len(pairs)} placed)", ErrorCode.RANGE)
    del pairs[index]
    storage.write_id_blob(target, LANDMARKS_PROP, LANDMARKS_SCHEMA, data)
    return len(pairs)


def clear_landmarks(target) -> None:
    if LANDMARKS_PROP in target:
        del target[LANDMARKS_PROP]


def set_landmarks(target, source, src_index, dst_index) -> int:
    """Replace the target's landmark pairs (each vertex used at most once); returns their number."""
    src = np.asarray(src_index, dtype=np.int64)
    dst = np.asarray(dst_index, dtype=np.int64)
    for a in src:
        _check_vertex(source, a, "the source rig")
    for b in dst:
        _check_vertex(target, b, "the target")
    seen_a, seen_b, pairs = set(), set(), []
    for a, b in zip(src.tolist(), dst.tolist()):
        if a not in seen_a and b not in seen_b:
            seen_a.add(a)
            seen_b.add(b)
            pairs.append((a, b))
    _store_pairs(target, source, pairs)
    return len(pairs)


def use_named_landmarks(target, source) -> int:
    """Set the target's transfer landmark pairs from the names placed on both the source rig and the target
    (:mod:`bridge.named_landmarks`); returns the number of pairs (refused below the minimum, naming how many)."""
    src, dst = named_landmarks.named_landmarks(source), named_landmarks.named_landmarks(target)
    both = core_named.shared_names(src, dst)
    if len(both) < MIN_LANDMARKS:
        raise ShapeSpaceError(f"{len(both)} named landmarks are placed on both {source.name!r} and {target.name!r}; "
                              f"at least {MIN_LANDMARKS} are needed", ErrorCode.TOO_FEW_LANDMARKS)
    return set_landmarks(target, source, [src[n] for n in both], [dst[n] for n in both])


def _openings(source, target, rig, tgt) -> list:
    """Eye and mouth openings from the lid and inner-lip contours between the named landmarks placed on both
    the source rig and the target (``core.authoring.contacts``); [] where they are not placed.  Stale or
    damaged named landmarks are refused by name (they would silently change the transfer)."""
    src, dst = named_landmarks.named_landmarks(source), named_landmarks.named_landmarks(target)
    if not src or not dst:
        return []
    return core_contacts.openings_from_named(rig.neutral, rig.triangles, src, tgt.neutral, tgt.triangles, dst)


def _snap(points: np.ndarray, index: np.ndarray, verts: np.ndarray) -> np.ndarray:
    """Vertex indices for landmark points (a free surface point, index −1, snaps to its closest vertex)."""
    from scipy.spatial import cKDTree
    index = np.asarray(index, dtype=np.int64).copy()
    free = index < 0
    if free.any():
        index[free] = cKDTree(verts).query(np.asarray(points)[free])[1]
    return index


def propose_landmarks(source, target, method: str = "auto") -> Result:
    """Propose landmark pairs and store them on the target (replacing the ones it had).

    ``method``: ``shapes`` (from the shape keys both meshes share), ``geometry`` (geometric features of
    both heads: for a target without shapes), ``auto`` (shapes when the target has shapes the source
    shares, else geometry), ``named`` (the named landmarks, :mod:`core.authoring.named`, proposed with a
    confidence each; the ones flagged as unsure are not stored while 5 others remain).  Returns the core
    result (value: the number of pairs stored); nothing is stored when it fails.
    """
    rig = read_source_rig(source)
    tgt = read_target(target)
    if method not in ("auto", "shapes", "geometry", "named"):
        raise ShapeSpaceError(f"unknown landmark method {method!r}: auto, shapes, geometry or named",
                              ErrorCode.METHOD)
    result = None
    if method in ("auto", "shapes") and len(tgt.keys) > 1:
        model = shapekeys.read_blendshape_model(target)
        try:
            result = core.landmarks_from_shared_shapes(rig.neutral, rig.deltas, rig.names, tgt.neutral,
                                                       model.deltas, model.names)
        except ShapeSpaceError:
            if method == "shapes":
                raise
            result = None
    elif method == "shapes":
        raise ShapeSpaceError(f"the target {target.name!r} has no shape keys to find landmarks from: use the "
                              f"geometric proposal", ErrorCode.NO_SHAPE_KEYS)
    if result is None or result.value is None or len(result.value.names) < MIN_LANDMARKS:
        if method == "shapes":
            found = 0 if result is None or result.value is None else len(result.value.names)
            raise ShapeSpaceError(f"only {found} shared shapes give a landmark; {MIN_LANDMARKS} are needed: use the "
                                  f"geometric proposal or place them by hand", ErrorCode.TOO_FEW_LANDMARKS)
        from ..core.authoring.proposal import propose_landmark_pairs
        result = propose_landmark_pairs(rig.neutral, rig.triangles, rig.full_sculpts(), rig.names, tgt.neutral,
                                        tgt.triangles, named=method == "named")
    if result.value is None:
        raise ShapeSpaceError(result.message or "no landmarks could be proposed", ErrorCode.TOO_FEW_LANDMARKS)
    pairs, message = _usable(result.value, result.message)
    src = _snap(pairs.source, pairs.source_index, rig.neutral)
    dst = _snap(pairs.target, pairs.target_index, tgt.neutral)
    count = set_landmarks(target, source, src, dst)
    return Result(count, status=result.status, message=message, diagnostics=dict(result.diagnostics),
                  issues=list(result.issues))


def _usable(pairs, message: str) -> tuple:
    """The proposed pairs to store: without the ones the proposal flagged as unsure while at least
    :data:`MIN_LANDMARKS` others remain (they are named in the message, to be placed by hand)."""
    kept = pairs.unflagged()
    if len(kept) == len(pairs) or len(kept) < MIN_LANDMARKS:
        return pairs, message
    return kept, f"{message} (the {len(pairs) - len(kept)} unsure ones are not used)"


def _landmarks_for(source, target, rig: SourceRig, tgt: TargetMesh):
    src, dst = landmark_pairs(target, source)
    if len(src) < MIN_LANDMARKS:
        raise ShapeSpaceError(f"{target.name!r} has {len(src)} landmark pairs; place at least {MIN_LANDMARKS} "
                              f"(Propose Landmarks, or Add Landmark on a selected vertex pair)",
                              ErrorCode.TOO_FEW_LANDMARKS)
    pairs = core.landmarks_from_indices(rig.neutral, tgt.neutral, src, dst)
    core.check_landmarks(pairs, rig.neutral, tgt.neutral)
    return pairs


# ------------------------------------------------------------------ registration and its preview
def register_source(source, target, progress=None) -> Result:
    """Register the source neutral onto the target (landmarks stored on the target); value: the correspondence
    (:func:`read_preview` and :func:`compute_preview` in one go, nothing shown)."""
    return compute_preview(read_preview(source, target), progress).result


def preview_object(target):
    """The registration preview object of ``target``, or None."""
    for ob in target.children:
        if PREVIEW_PROP in ob and ob.library is None:
            return ob
    return None


def clear_preview(target) -> bool:
    """Remove the target's registration preview object and its mesh (nothing is left behind)."""
    ob = preview_object(target)
    if ob is None:
        return False
    mesh = ob.data
    bpy.data.objects.remove(ob)
    if mesh is not None and mesh.users == 0:
        bpy.data.meshes.remove(mesh)
    return True


def _triangle_mesh(name: str, verts: np.ndarray, tris: np.ndarray):
    me = bpy.data.meshes.new(name)
    me.vertices.add(len(verts))
    write_float(me.vertices, "co", verts)
    me.loops.add(tris.size)
    me.loops.foreach_set("vertex_index", np.ascontiguousarray(tris, dtype=np.int32).ravel())
    me.polygons.add(len(tris))
    me.polygons.foreach_set("loop_start", np.arange(0, tris.size, 3, dtype=np.int32))
    me.update(calc_edges=True)
    me.validate()
    return me


@dataclass
class PreviewPlan:
    """What a registration preview needs, read from Blender (:func:`read_preview`); no Blender references."""

    source: str
    target: str
    rig: SourceRig
    tgt: TargetMesh
    pairs: object                        # core.LandmarkPairs
    signature: tuple                     # the target as read (see _target_signature)


def read_preview(source, target) -> PreviewPlan:
    """Step 1 of :func:`show_preview` (main thread): read the source rig, the target and its landmark pairs."""
    rig = read_source_rig(source)
    tgt = read_target(target)
    pairs = _landmarks_for(source, target, rig, tgt)
    return PreviewPlan(source=source.name, target=target.name, rig=rig, tgt=tgt, pairs=pairs,
                       signature=_target_signature(target))


@dataclass
class PreviewOutcome:
    """What :func:`compute_preview` computed; :func:`write_preview` shows it."""

    plan: PreviewPlan
    result: Result                       # the registration (value: the correspondence)


def compute_preview(plan: PreviewPlan, progress=None) -> PreviewOutcome:
    """Step 2 (any thread; touches no Blender data): the registration; raising
    :class:`~core.progress.Cancelled` from ``progress`` stops it."""
    result = core.register(plan.rig.neutral, plan.rig.triangles, plan.tgt.neutral, plan.tgt.triangles, plan.pairs,
                           progress=progress)
    if result.value is None or result.status == Status.FAILED:
        raise ShapeSpaceError(f"registration of {plan.source!r} onto {plan.target!r} failed: "
                              f"{result.message or 'no result'}", ErrorCode.DEGENERATE)
    return PreviewOutcome(plan=plan, result=result)


def write_preview(outcome: PreviewOutcome) -> tuple:
    """Step 3 (main thread): replace the target's preview object by the registered source neutral.

    Refused, with nothing written, when the target is gone or changed since :func:`read_preview`.  The preview
    is one object (parented to the target, not selectable, not rendered), removed with its mesh by
    :func:`clear_preview` and by a transfer.  Returns ``(preview object, registration result)``.
    """
    plan, result = outcome.plan, outcome.result
    target = bpy.data.objects.get(plan.target)
    if target is None or target.type != "MESH" or _target_signature(target) != plan.signature:
        raise ShapeSpaceError(f"{plan.target!r} changed while the registration computed: nothing was shown; "
                              "preview again", ErrorCode.RIG_CHANGED)
    clear_preview(target)
    name = f"{target.name} Registration Preview"
    me = _triangle_mesh(name, np.asarray(result.value.registered, dtype=np.float64), plan.rig.triangles)
    ob = bpy.data.objects.new(name, me)
    ob[PREVIEW_PROP] = target.name
    ob.display_type = "WIRE"
    ob.show_in_front = True
    ob.hide_render = True
    ob.hide_select = True
    collection = target.users_collection[0] if target.users_collection else bpy.context.scene.collection
    collection.objects.link(ob)
    ob.parent = target
    ob.matrix_parent_inverse.identity()
    return ob, result


def show_preview(source, target, progress=None) -> tuple:
    """Register and show the registered source neutral as a wireframe object over the target (the three steps
    :func:`read_preview`, :func:`compute_preview`, :func:`write_preview` in one go)."""
    return write_preview(compute_preview(read_preview(source, target), progress))


def start_preview_job(plan: PreviewPlan) -> BackgroundJob:
    """Start :func:`compute_preview` of ``plan`` in a worker thread (a modal operator polls it and cancels it on
    Esc); :func:`finish_preview_job` shows the result once it is done."""
    return BackgroundJob(lambda progress: compute_preview(plan, progress), name="ShapeSpace registration").start()


def finish_preview_job(job: BackgroundJob) -> tuple:
    """Show a finished job's registration (main thread); re-raises what stopped the job (``Cancelled``, its
    :class:`ShapeSpaceError`), nothing is written then."""
    return write_preview(job.result())


# ------------------------------------------------------------------ transfer
@dataclass
class TransferReport:
    """What a transfer did (the command line prints it as JSON)."""

    source: str
    target: str
    created: list = field(default_factory=list)          # new key names, in order
    overwritten: list = field(default_factory=list)
    skipped: list = field(default_factory=list)          # existing names kept ("skip") and their dependents
    empty: list = field(default_factory=list)            # source shapes that move nothing (created all the same)
    inbetweens: list = field(default_factory=list)
    combinations: list = field(default_factory=list)
    vertex_groups: list = field(default_factory=list)
    landmarks: int = 0
    registration_residual_mm: float = 0.0
    registration_status: str = "ok"
    seconds: float = 0.0
    warnings: list = field(default_factory=list)
    status: str = "ok"                                   # "warning" when a per-key check failed (CLI exit 1)
    keys: list = field(default_factory=list)             # per-key checks (core.authoring.quality.check_keys)
    parts: list = field(default_factory=list)            # per-part kind, size, confidence, reason
    part_objects: list = field(default_factory=list)     # per part object: keys created / overwritten / skipped
    openings: list = field(default_factory=list)         # eye / mouth openings whose closure was carried

    def to_json(self) -> dict:
        return to_jsonable(self)


def _new_names(rig: SourceRig, naming: str) -> dict:
    """Source key name → target key name in the chosen convention (driven keys follow their primaries)."""
    if naming not in NAMINGS:
        raise ShapeSpaceError(f"unknown naming {naming!r}: {', '.join(NAMINGS)}", ErrorCode.METHOD)
    out = {}
    for n in rig.names:
        if n not in rig.inbetweens and n not in rig.combinations:
            out[n] = n if naming == "source" else core.convert_name(n, naming)
    for n, v in rig.inbetweens.items():
        default = f"{v['primary']}@{v['at']:g}"
        out[n] = f"{out[v['primary']]}@{v['at']:g}" if n == default else (
            n if naming == "source" else core.convert_name(n, naming))
    for n, v in rig.combinations.items():
        out[n] = "+".join(out[i] for i in v["inputs"]) if n == "+".join(v["inputs"]) else (
            n if naming == "source" else core.convert_name(n, naming))
    by_new = {}
    for old, new in out.items():
        if len(new.encode("utf-8")) > 63:
            raise ShapeSpaceError(f"the new name of {old!r} is longer than Blender's 63 bytes: {new!r}",
                                  ErrorCode.RESERVED_NAME)
        if new in by_new:
            raise ShapeSpaceError(f"source keys {by_new[new]!r} and {old!r} both become {new!r} in this naming "
                                  f"convention: rename one, or keep the source names", ErrorCode.DUPLICATE_NAME)
        by_new[new] = old
    return out


def _plan(rig: SourceRig, tgt: TargetMesh, names: dict, existing: str, target_obj, groups: bool = True) -> tuple:
    """Which source keys are written, which target keys are replaced, which are skipped (by policy); masks
    (vertex groups) only where ``groups``."""
    if existing not in EXISTING:
        raise ShapeSpaceError(f"unknown policy for existing keys {existing!r}: {', '.join(EXISTING)}",
                              ErrorCode.METHOD)
    have = set(tgt.keys)
    reference = tgt.keys[0] if tgt.keys else None
    clash = [n for n in rig.names if names[n] in have]
    if clash and existing == "refuse":
        shown = ", ".join(names[n] for n in clash[:6]) + (f" … ({len(clash)} in all)" if len(clash) > 6 else "")
        raise ShapeSpaceError(f"{tgt.name!r} already has shape keys named {shown}: choose to skip or "
                              f"overwrite existing keys (nothing was changed)", ErrorCode.DUPLICATE_NAME)
    if reference is not None and existing == "overwrite" and any(names[n] == reference for n in clash):
        raise ShapeSpaceError(f"a source key would replace the basis {reference!r} of {tgt.name!r}: rename it or "
                              f"skip existing keys", ErrorCode.RESERVED_NAME)
    skip = set(clash) if existing == "skip" else set()
    # driven keys whose primary / inputs were skipped are skipped too (their correction belongs to our primary)
    for n, v in rig.inbetweens.items():
        if v["primary"] in skip:
            skip.add(n)
    for n, v in rig.combinations.items():
        if any(i in skip for i in v["inputs"]):
            skip.add(n)
    write = [n for n in rig.names if n not in skip]
    replace = [names[n] for n in write if names[n] in have]
    groups_clash = sorted({rig.groups[n] for n in write if n in rig.groups
                           and rig.groups[n] in target_obj.vertex_groups}) if groups else []
    if groups_clash and existing == "refuse":
        raise ShapeSpaceError(f"{tgt.name!r} already has vertex groups named {', '.join(groups_clash)} (masks of "
                              f"the source keys): choose to skip or overwrite existing keys", ErrorCode.DUPLICATE_NAME)
    return write, replace, sorted(skip, key=rig.names.index), groups_clash


def _map_weights(corr, src_tris: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Per-vertex source values at each target vertex's corresponding source point (0 where unmapped)."""
    tri = np.asarray(corr.tri, dtype=np.int64)
    ok = tri >= 0
    out = np.zeros(len(tri), dtype=np.float64)
    corners = src_tris[tri[ok]]                                  # (m, 3)
    out[ok] = np.einsum("ij,ij->i", np.asarray(corr.bary, dtype=np.float64)[ok], weights[corners])
    return np.clip(out, 0.0, 1.0)


def _fill_group(group, weights: np.ndarray) -> None:
    rounded = np.round(weights / _WEIGHT_STEP) * _WEIGHT_STEP
    for w in np.unique(rounded[rounded > 0]):
        group.add(np.flatnonzero(rounded == w).tolist(), float(w), "REPLACE")


def _set_range(kb, lo: float, hi: float) -> None:
    kb.slider_max = 10.0
    kb.slider_min = float(lo)
    kb.slider_max = float(hi)


def _write(target, rig: SourceRig, names: dict, write: list, replace: list, full: np.ndarray, base: np.ndarray,
           masks: dict, replace_groups: bool, report: TransferReport) -> None:
    """Write every new key (plain ones, then in-betweens and combinations through the driven verbs).

    Keys and mask groups that replace existing ones are written under temporary names first; only when
    everything is written are the old ones removed and the new ones renamed (drivers that referred to an
    old key by name then find the new one).  Any failure before that removes everything new and restores
    the driven-key blob, so the file is as before.
    """
    index = {n: i for i, n in enumerate(rig.names)}
    made_key = target.data.shape_keys is None
    old_keys = set() if made_key else {kb.name for kb in target.data.shape_keys.key_blocks}
    old_groups = {g.name for g in target.vertex_groups}
    old_meta = None if made_key else target.data.shape_keys.get(driven.PROP)
    replacing = set(replace)
    live = {n: (f"{_TMP}{i}" if names[n] in replacing else names[n]) for i, n in enumerate(write)}
    new_groups, swap_groups = [], {}
    try:
        if made_key:
            target.shape_key_add(name="Basis", from_mix=False)
        blocks = target.data.shape_keys.key_blocks
        group_names = {}
        for j, (group, weights) in enumerate(masks.items()):
            if group in old_groups and not replace_groups:
                group_names[group] = group                       # "skip": the target's own group is kept
                continue
            made = target.vertex_groups.new(name=group if group not in old_groups else f"{_TMP}g{j}")
            new_groups.append(made.name)
            _fill_group(made, weights)
            group_names[group] = group
            if group in old_groups:
                swap_groups[made.name] = group
        for n in write:
            if n in rig.inbetweens or n in rig.combinations:
                continue
            kb = target.shape_key_add(name=live[n], from_mix=False)
            write_float(kb.data, "co", base + full[index[n]])
        for n in [n for n in write if n in rig.inbetweens] + [n for n in write if n in rig.combinations]:
            tmp = target.shape_key_add(name=_TMP, from_mix=False)
            write_float(tmp.data, "co", base + full[index[n]])
            if n in rig.inbetweens:
                v = rig.inbetweens[n]
                driven.add_inbetween(target, live.get(v["primary"], names[v["primary"]]), tmp.name,
                                     float(v["at"]), name=live[n])
                report.inbetweens.append(names[n])
            else:
                inputs = [live.get(i, names[i]) for i in rig.combinations[n]["inputs"]]
                driven.add_combination(target, inputs, tmp.name, name=live[n])
                report.combinations.append(names[n])
        for n in write:
            kb = blocks[live[n]]
            i = index[n]
            _set_range(kb, rig.slider_min[i], rig.slider_max[i])
            kb.mute = bool(rig.mute[i])
            kb.value = 0.0
            if n in rig.groups:
                kb.vertex_group = group_names[rig.groups[n]]
    except Exception:
        _undo_write(target, old_keys, new_groups, made_key, old_meta)
        raise
    # everything is written: now replace the old keys and groups (plain renames and removals)
    for name in replace:                                         # validated: never the reference key
        old = blocks[name]
        old.driver_remove("value")
        target.shape_key_remove(old)
    for n in write:
        if live[n] != names[n]:
            blocks[live[n]].name = names[n]                      # drivers referring to it follow the rename
    for tmp_name, final in swap_groups.items():
        target.vertex_groups.remove(target.vertex_groups[final])
        target.vertex_groups[tmp_name].name = final
    if replace:
        key = target.data.shape_keys
        storage.write_id_blob(key, driven.PROP, driven.SCHEMA, driven.prune(key))
    report.overwritten = list(replace)
    report.created = [names[n] for n in write]
    report.vertex_groups = sorted(group_names.values())
    target.data.update()


def _undo_write(target, old_keys: set, groups: list, made_key: bool, old_meta) -> None:
    """Remove what :func:`_write` made (every key not there before, with its driver; new groups) and restore
    the driven-key blob."""
    key = target.data.shape_keys
    if key is not None and not made_key:
        if old_meta is None:
            key.pop(driven.PROP, None)
        else:
            key[driven.PROP] = old_meta
    if key is not None:
        for kb in [kb for kb in key.key_blocks if kb.name not in old_keys and kb != key.reference_key]:
            target.shape_key_remove(kb)
        if made_key and target.data.shape_keys is not None:
            target.shape_key_clear()
    for name in groups:
        g = target.vertex_groups.get(name)
        if g is not None:
            target.vertex_groups.remove(g)


@dataclass
class TransferPlan:
    """Everything a transfer needs, read from Blender (:func:`read_transfer`); no Blender references."""

    source: str
    target: str
    rig: SourceRig
    tgt: TargetMesh
    pairs: object                        # core.LandmarkPairs
    names: dict                          # source key name → new name
    write: list                          # source keys to write, in order
    replace: list                        # target keys they replace
    skipped: list
    groups_clash: list
    existing: str
    unmatched_parts: str
    signature: tuple                     # the target as read (see _target_signature)
    started: float
    part_plans: list = field(default_factory=list)   # (PartObject, write, replace, skipped) per part object
    openings: list = field(default_factory=list)     # core.authoring.contacts.Opening (named lid/lip contours)


@dataclass
class TransferOutcome:
    """What :func:`compute_transfer` computed; :func:`write_transfer` writes it."""

    plan: TransferPlan
    full: np.ndarray                     # (n, q, 3) transferred sculpt of every source key (zero for unwritten)
    masks: dict                          # vertex-group name → (q,) mapped weights
    report: TransferReport


def _target_signature(target, parts=()) -> tuple:
    """What a transfer's write depends on: mode, link state, vertices (the neutral), shape keys and groups."""
    key = target.data.shape_keys
    keys = tuple(kb.name for kb in key.key_blocks) if key is not None else ()
    return (target.mode, target.library is not None or target.data.library is not None, len(target.data.vertices),
            _neutral(target).tobytes(), keys, tuple(g.name for g in target.vertex_groups),
            part_objects.signature(target, list(parts)))


def _with_part_objects(target, source, tgt: TargetMesh, parts) -> TargetMesh:
    """``tgt`` with the part objects appended (their rows after the target's own)."""
    verts, tris, objects = part_objects.read_part_objects(target, source, parts, len(tgt.neutral), triangles,
                                                          _finite)
    if not objects:
        return tgt
    neutral, tri = np.vstack([tgt.neutral, verts]), np.vstack([tgt.triangles, tris])
    return TargetMesh(name=tgt.name, neutral=neutral, triangles=tri, keys=tgt.keys,
                      parts=len(core.triangle_parts(len(neutral), tri)[1]), own=len(tgt.neutral), objects=objects)


def _part_plans(rig, tgt: TargetMesh, names: dict, existing: str) -> list:
    """Each part object's keys to write / replace / skip under the same policy (no masks on part objects)."""
    out = []
    for p in tgt.objects:
        ob = bpy.data.objects[p.name]
        mesh = TargetMesh(name=p.name, neutral=np.zeros((0, 3)), triangles=np.zeros((0, 3), int), keys=p.keys,
                          parts=0)
        write, replace, skipped, _ = _plan(rig, mesh, names, existing, ob, groups=False)
        out.append((p, write, replace, skipped))
    return out


def read_transfer(source, target, naming: str = "source", existing: str = "refuse",
                  unmatched_parts: str = "keep", parts=None) -> TransferPlan:
    """Step 1 of :func:`transfer_shapes` (main thread): validate and read everything; writes nothing.
    ``parts``: part objects transferred with the target (:func:`bridge.part_objects.meshes_of`)."""
    start = time.perf_counter()
    if source is not None and target is not None and source == target:
        raise ShapeSpaceError("the source rig and the target are the same object", ErrorCode.SAME_KEY)
    if unmatched_parts not in ("move", "keep", "refuse"):
        raise ShapeSpaceError(f"unknown unmatched-parts policy {unmatched_parts!r}: move, keep or refuse",
                              ErrorCode.METHOD)
    rig = read_source_rig(source)
    tgt = read_target(target)
    if target.library is not None or target.data.library is not None:
        raise ShapeSpaceError(f"{target.name!r} is linked from a library: make it local first", ErrorCode.LINKED)
    parts = list(parts or ())
    tgt = _with_part_objects(target, source, tgt, parts)
    names = _new_names(rig, naming)
    write, replace, skipped, groups_clash = _plan(rig, tgt, names, existing, target)
    part_plans = _part_plans(rig, tgt, names, existing)
    openings = _openings(source, target, rig, tgt)
    if not write:
        raise ShapeSpaceError(f"{target.name!r} already has every shape of {source.name!r}: nothing to transfer",
                              ErrorCode.NO_TARGETS)
    pairs = _landmarks_for(source, target, rig, tgt)
    return TransferPlan(source=source.name, target=target.name, rig=rig, tgt=tgt, pairs=pairs, names=names,
                        write=write, replace=replace, skipped=skipped, groups_clash=groups_clash, existing=existing,
                        unmatched_parts=unmatched_parts, signature=_target_signature(target, parts), started=start,
                        part_plans=part_plans, openings=openings)


def compute_transfer(plan: TransferPlan, progress=None) -> TransferOutcome:
    """Step 2 (any thread; touches no Blender data): registration, deformation transfer, mapped masks.

    ``progress(fraction)`` (:mod:`core.progress`) is called through the registration and between the shape
    chunks; raising :class:`~core.progress.Cancelled` from it stops the work before anything is written.
    """
    rig, tgt, names, write = plan.rig, plan.tgt, plan.names, plan.write
    report = TransferReport(source=plan.source, target=plan.target, skipped=[names[n] for n in plan.skipped])
    notify(progress, 0.0)
    result = core.register(rig.neutral, rig.triangles, tgt.neutral, tgt.triangles, plan.pairs,
                           progress=scaled(progress, 0.0, 0.6))
    if result.value is None or result.status == Status.FAILED:
        raise ShapeSpaceError(f"registration of {plan.source!r} onto {plan.target!r} failed: "
                              f"{result.message or 'no result'}", ErrorCode.DEGENERATE)
    corr = result.value
    report.landmarks = len(plan.pairs)
    report.registration_residual_mm = float(getattr(corr, "residual_mm", result.diagnostics.get("residual_mm", 0.0)))
    report.registration_status = {Status.OK: "ok", Status.WARNING: "warning",
                                  Status.NOT_CONVERGED: "not_converged"}.get(result.status, "ok")
    if result.status != Status.OK and result.message:
        report.warnings.append(f"registration: {result.message}")
    moving = plan.unmatched_parts == "move"
    openings = core_contacts.with_references(plan.openings, rig.neutral, rig.full_sculpts(), rig.names)
    transfer = core.Transfer(rig.neutral, rig.triangles, tgt.neutral, tgt.triangles, corr,
                             unmatched_parts="keep" if moving else plan.unmatched_parts, openings=openings)
    if not moving:
        report.warnings.extend(issue.message for issue in transfer.issues)
    notify(progress, 0.7)
    rows = [rig.names.index(n) for n in write]
    sculpts = rig.full_sculpts()[rows]
    chunk = 8                                    # the core solves 8 shapes at a time: same numbers, progress between
    solved = np.zeros((len(rows),) + tgt.neutral.shape)
    for c0 in range(0, len(rows), chunk):
        solved[c0:c0 + chunk] = transfer.solve(sculpts[c0:c0 + chunk])
        notify(progress, 0.7 + 0.25 * min(len(rows), c0 + chunk) / len(rows))
    if not np.isfinite(solved).all():
        bad = write[int(np.argwhere(~np.isfinite(solved))[0][0])]
        raise ShapeSpaceError(f"the transfer of {bad!r} produced non-finite positions: nothing was written",
                              ErrorCode.NON_FINITE)
    _check_and_move_parts(rig, tgt, write, sculpts, solved, corr, moving, report, plan.openings)
    full = np.zeros((len(rig.names),) + tgt.neutral.shape)
    full[rows] = solved
    scale = float(np.linalg.norm(np.ptp(rig.neutral, axis=0))) or 1.0
    report.empty = [names[n] for n, d in zip(write, sculpts) if np.abs(d).max() <= 1e-9 * scale]
    masks = {}
    for n in write:
        group = rig.groups.get(n)
        if group is not None and group not in masks:
            masks[group] = _map_weights(corr, rig.triangles, rig.group_weights[group])
    notify(progress, 1.0)
    return TransferOutcome(plan=plan, full=full, masks=masks, report=report)


def _check_and_move_parts(rig, tgt, write, sculpts, solved, corr, moving, report, openings) -> None:
    """Move the target's parts (policy ``move``, in place) and run the per-key checks into ``report``."""
    plan, moved = None, None
    if moving:
        plan = core_parts.plan_for_transfer(rig.neutral, rig.triangles, sculpts, write, tgt.neutral, tgt.triangles,
                                            solved, corr.part_map)
        solved, moved = core_parts.move_parts(plan, tgt.neutral, tgt.triangles, solved, write)
        report.parts = plan.summary()
    keys, issues, status = core_quality.check_keys(rig.neutral, sculpts, write, tgt.neutral, solved, plan=plan,
                                                   moved=moved, src_tris=rig.triangles, dst_tris=tgt.triangles,
                                                   openings=openings)
    report.openings = [o.name for o in openings]
    report.keys = keys
    report.warnings.extend(issue.message for issue in issues)
    report.status = "warning" if status != Status.OK else "ok"


def _write_part_objects(outcome: TransferOutcome, report: TransferReport) -> None:
    """Each part object gets its keys (its rows of the result, in its own object space), after the head."""
    plan = outcome.plan
    for p, write, replace, skipped in plan.part_plans:
        ob = bpy.data.objects[p.name]
        own = TransferReport(source=plan.source, target=p.name)
        local = part_objects.to_part_space(p, outcome.full[:, p.start:p.start + p.count])
        _write(ob, plan.rig, plan.names, write, replace, local, part_objects.own_neutral(ob), {},
               plan.existing == "overwrite", own)
        report.part_objects.append({"object": p.name, "created": own.created, "overwritten": own.overwritten,
                                    "skipped": [plan.names[n] for n in skipped]})


#: Shape-key custom property of a transfer target: the last transfer's verdict for the panel.
LAST_PROP = "shapespace_last_transfer"
LAST_SCHEMA = blobs.TRANSFER_LAST.schema


def _store_verdict(target, report: TransferReport) -> None:
    """Keep the last transfer's verdict on the target's keys (what the panel shows): status, the failed checks
    per key, the parts' kinds, the openings carried."""
    failed = [[k["name"], list(k["failed"])] for k in report.keys if k["failed"]]
    parts = [[p["part"], p["kind"], p["vertices"], bool(p["unsure"])] for p in report.parts]
    storage.write_id_blob(target.data.shape_keys, LAST_PROP, LAST_SCHEMA,
                          {"source": report.source, "status": report.status, "failed": failed, "parts": parts,
                           "openings": list(report.openings)})


def last_verdict(target) -> dict | None:
    """The last transfer's stored verdict on ``target`` (see :func:`_store_verdict`), or None."""
    key = target.data.shape_keys if target is not None and target.type == "MESH" else None
    if key is None or LAST_PROP not in key:
        return None
    return storage.read_id_blob(key, LAST_PROP, LAST_SCHEMA)


def verdict_status(target) -> tuple:
    """``(verdict or None, problem)`` for panels: never raises (``problem`` is '' or one line)."""
    try:
        return last_verdict(target), ""
    except ShapeSpaceError as exc:
        return None, str(exc)


def write_transfer(outcome: TransferOutcome) -> TransferReport:
    """Step 3 (main thread): write the new keys (and mask groups) in one step; returns the report.

    Refused, with nothing written, when the target is gone or changed (mode, vertices, shape keys, vertex
    groups) since :func:`read_transfer`.
    """
    plan, report = outcome.plan, outcome.report
    target = bpy.data.objects.get(plan.target)
    parts = [bpy.data.objects.get(p.name) for p in plan.tgt.objects]
    if target is None or target.type != "MESH" or _target_signature(target, parts) != plan.signature:
        raise ShapeSpaceError(f"{plan.target!r} changed while the transfer computed (mode, mesh, shape keys, "
                              "vertex groups or part objects): nothing was written; transfer again",
                              ErrorCode.RIG_CHANGED)
    own = plan.tgt.own if plan.tgt.own >= 0 else len(plan.tgt.neutral)
    _write(target, plan.rig, plan.names, plan.write, plan.replace, outcome.full[:, :own], plan.tgt.neutral[:own],
           {g: w[:own] for g, w in outcome.masks.items()}, plan.existing == "overwrite", report)
    _write_part_objects(outcome, report)
    _store_verdict(target, report)
    clear_preview(target)                       # it served its purpose; the result file does not keep it
    report.skipped = [plan.names[n] for n in plan.skipped] + (
        [f"vertex group {g} (kept)" for g in plan.groups_clash] if plan.existing == "skip" else [])
    report.seconds = time.perf_counter() - plan.started
    return report


def start_transfer_job(plan: TransferPlan) -> BackgroundJob:
    """Start :func:`compute_transfer` of ``plan`` in a worker thread (a modal operator polls the job and
    cancels it on Esc); :func:`finish_transfer_job` writes its outcome once it is done."""
    return BackgroundJob(lambda progress: compute_transfer(plan, progress), name="ShapeSpace transfer").start()


def finish_transfer_job(job: BackgroundJob) -> TransferReport:
    """Write a finished job's outcome (main thread, one step) and return its report.

    Re-raises what stopped the job (:class:`~core.progress.Cancelled` when it was cancelled, its
    :class:`ShapeSpaceError`); nothing is written then."""
    try:
        outcome = job.result()
    except MemoryError:
        raise ShapeSpaceError("not enough memory for this transfer (decimate the target, or transfer fewer "
                              "shapes)", ErrorCode.TOO_LARGE) from None
    return write_transfer(outcome)


def transfer_shapes(source, target, naming: str = "source", existing: str = "refuse", unmatched_parts: str = "keep",
                    progress=None, parts=None) -> TransferReport:
    """Transfer every shape key of ``source`` onto ``target``: :func:`read_transfer` → :func:`compute_transfer`
    → :func:`write_transfer` (validate → compute → write).

    Parameters
    ----------
    source, target : bpy.types.Object
        Meshes; the target may have any topology and vertex count and needs ≥ 5 landmark pairs.
    naming : {"source", "arkit", "suffix", "pascal"}
    existing : {"refuse", "skip", "overwrite"}
        Target keys (and mask vertex groups) that already have a new name: refuse naming them (default),
        keep them (their in-betweens/combinations are skipped too), or replace them.
    unmatched_parts : {"move", "keep", "refuse"}
        Separate parts of the target the source does not have (eyes, teeth, lashes): they move as rigged
        (:mod:`core.authoring.parts`; the panel's and the command line's default), stay still (this
        function's default, as before 0.2), or refuse.
    progress : callable(fraction) or None
        :mod:`core.progress` protocol; raising :class:`~core.progress.Cancelled` from it stops the transfer
        with nothing written.
    parts : sequence of bpy.types.Object, optional
        Part objects (eyes, teeth as meshes of their own) transferred with the target; each gets shape keys
        of the same names (:mod:`bridge.part_objects`).

    Raises
    ------
    core.ShapeSpaceError
        Before anything is written; the file is unchanged.
    """
    plan = read_transfer(source, target, naming, existing, unmatched_parts, parts)
    return write_transfer(compute_transfer(plan, progress))


# ------------------------------------------------------------------ a source rig from another .blend (command line)
_ID_COLLECTIONS = ("actions", "armatures", "brushes", "cache_files", "cameras", "collections", "curves", "fonts",
                   "grease_pencils", "grease_pencils_v3", "hair_curves", "images", "lattices", "libraries",
                   "lightprobes", "lights", "linestyles", "masks", "materials", "meshes", "metaballs", "movieclips",
                   "node_groups", "objects", "paint_curves", "palettes", "particles", "pointclouds", "scenes",
                   "screens", "shape_keys", "sounds", "speakers", "texts", "textures", "volumes", "workspaces",
                   "worlds")


def _all_ids() -> dict:
    out = {}
    for attr in _ID_COLLECTIONS:
        coll = getattr(bpy.data, attr, None)
        if coll is None:
            continue
        for idb in coll:
            out[idb.as_pointer()] = idb
    return out


def append_object(path: str, name: str) -> tuple:
    """Append object ``name`` (with what it uses) from the .blend ``path``, local to this file.

    Returns ``(object, appended)``: ``appended`` lists every datablock the append created, for
    :func:`remove_appended` (the output file keeps none of them).
    """
    import os
    if not os.path.isfile(path):
        raise ShapeSpaceError(f"file not found: {path}", ErrorCode.MISSING_FILE)
    before = set(_all_ids())
    try:
        with bpy.data.libraries.load(path, link=False) as (data_from, data_to):
            if name not in data_from.objects:
                shown = ", ".join(sorted(data_from.objects)[:8])
                raise ShapeSpaceError(f"{path} has no object named {name!r} (objects: {shown or 'none'})",
                                      ErrorCode.MISSING_OBJECT)
            data_to.objects = [name]
    except OSError as exc:
        raise ShapeSpaceError(f"cannot read {path}: {exc}", ErrorCode.CORRUPT_FILE) from None
    appended = [idb for ptr, idb in _all_ids().items() if ptr not in before]
    obj = next((o for o in data_to.objects if o is not None), None)
    if obj is None:
        remove_appended(appended)
        raise ShapeSpaceError(f"cannot append {name!r} from {path}", ErrorCode.CORRUPT_FILE)
    return obj, appended


def remove_appended(appended: list) -> None:
    """Remove the datablocks :func:`append_object` created (nothing else of the file is touched)."""
    alive = set(_all_ids())
    ids = []
    for idb in appended:
        try:
            if idb.as_pointer() in alive:
                ids.append(idb)
        except ReferenceError:        # already gone
            continue
    if ids:
        bpy.data.batch_remove(ids)
