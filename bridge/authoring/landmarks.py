"""Landmark pairs of a transfer, kept per target object (a versioned blob, ``Object['shapespace_landmarks']``).

Placed by hand (:func:`add_landmark`, :func:`set_landmarks`), from the named landmarks placed on both meshes
(:func:`use_named_landmarks`), or proposed (:func:`propose_landmarks`: from the shapes both meshes share, or
from the heads' geometry); :func:`landmark_pairs` refuses pairs that became stale.  Also the eye and mouth
openings between the named landmarks (:func:`openings`).
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ...core import blobs
from ...core.authoring import contacts as core_contacts
from ...core.authoring import named as core_named
from ...core.authoring.job import SourceRig, TargetMesh
from ...core.authoring.landmarks import (
    LandmarkPairs,
    check_landmarks,
    landmarks_from_indices,
    landmarks_from_shared_shapes,
)
from ...core.authoring.proposal import propose_landmark_pairs
from ...core.errors import ErrorCode
from ...core.result import Result, ShapeSpaceError
from .. import named_landmarks, shapekeys, storage
from .reading import mesh_object, read_source_rig, read_target

__all__ = ["MIN_LANDMARKS", "LANDMARKS_PROP", "LANDMARKS_SCHEMA", "landmark_pairs", "landmark_count",
           "landmark_list", "selected_vertex", "add_landmark", "remove_landmark", "set_landmarks", "clear_landmarks",
           "use_named_landmarks", "propose_landmarks", "openings", "landmarks_for"]

MIN_LANDMARKS = 5

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
    mesh_object(source, "source rig")
    mesh_object(target, "target")
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


def openings(source, target, rig: SourceRig, tgt: TargetMesh) -> list:
    """Eye and mouth openings from the lid and inner-lip contours between the named landmarks placed on both
    the source rig and the target (``core.authoring.contacts``); [] where they are not placed.  Stale or
    damaged named landmarks are refused by name (they would silently change the transfer)."""
    src, dst = named_landmarks.named_landmarks(source), named_landmarks.named_landmarks(target)
    if not src or not dst:
        return []
    return core_contacts.openings_from_named(rig.neutral, rig.triangles, src, tgt.neutral, tgt.triangles, dst)


def _snap(points: np.ndarray, index: np.ndarray, verts: np.ndarray) -> np.ndarray:
    """Vertex indices for landmark points (a free surface point, index −1, snaps to its closest vertex)."""
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
            result = landmarks_from_shared_shapes(rig.neutral, rig.deltas, rig.names, tgt.neutral,
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


def landmarks_for(source, target, rig: SourceRig, tgt: TargetMesh) -> LandmarkPairs:
    """The target's stored pairs as core landmarks (at least :data:`MIN_LANDMARKS`, not stale, checked)."""
    src, dst = landmark_pairs(target, source)
    if len(src) < MIN_LANDMARKS:
        raise ShapeSpaceError(f"{target.name!r} has {len(src)} landmark pairs; place at least {MIN_LANDMARKS} "
                              f"(Propose Landmarks, or Add Landmark on a selected vertex pair)",
                              ErrorCode.TOO_FEW_LANDMARKS)
    pairs = landmarks_from_indices(rig.neutral, tgt.neutral, src, dst)
    check_landmarks(pairs, rig.neutral, tgt.neutral)
    return pairs
