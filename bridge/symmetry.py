"""Mirror maps on meshes and the shape-key verbs that use them (see :mod:`core.symmetry`).

The map is stored on the mesh datablock as the versioned JSON blob ``mesh["shapespace_mirror_map"]`` with a
topology fingerprint (vertex, edge and face counts and a hash of the edge list).  Reading a map whose
fingerprint no longer matches the mesh (vertices added, deleted or reordered) is refused with a message that
says to rebuild it.

Every verb validates and computes everything before it writes anything: on failure the file is as before.
Keys are created with their delta baked (a source key's vertex-group mask is applied to the delta, so the new
key evaluates as the masked source does), and nothing is deleted or overwritten without the artist asking.
"""
from __future__ import annotations

import numpy as np

from ..core import blobs
from ..core import symmetry as core_sym
from ..core.errors import ErrorCode
from ..core.result import Issue, ShapeSpaceError
from ..core.validate import coordinates, in_range
from . import storage
from .arrays import read_float, write_float
from .meshes import group_weight_vector, triangles

#: ``{"mirror": [int], "axis": int, "offset": float, "method": str, "tolerance": float,
#: "topology": {"vertices", "edges", "faces", "edge_hash"}, "coverage": float}``
PROP = blobs.MIRROR_MAP.prop
SCHEMA = blobs.MIRROR_MAP.schema

METHODS = ("AUTO", "POSITION", "TOPOLOGY")


def _read_int(collection, attr: str, width: int) -> np.ndarray:
    buf = np.empty(len(collection) * width, dtype=np.int32)
    if buf.size:
        collection.foreach_get(attr, buf)
    return buf.reshape(-1, width) if width > 1 else buf


def rest_positions(obj) -> np.ndarray:
    """The basis key's coordinates (the stored vertex positions when there are no keys), float64 (p, 3)."""
    me = obj.data
    key = me.shape_keys
    src = key.reference_key.points if key is not None and len(key.key_blocks) else me.vertices
    co = read_float(src, "co", 3).astype(np.float64)
    if not np.isfinite(co).all():
        v = int(np.argwhere(~np.isfinite(co))[0][0])
        raise ShapeSpaceError(f"{obj.name!r} has a non-finite rest coordinate at vertex {v}", ErrorCode.NON_FINITE)
    return co


def fingerprint(mesh) -> dict:
    """:func:`core.symmetry.topology_fingerprint` of a ``bpy.types.Mesh``."""
    return core_sym.topology_fingerprint(len(mesh.vertices), _read_int(mesh.edges, "vertices", 2),
                                         len(mesh.polygons))


def topology(obj, positions=None) -> core_sym.Topology:
    """The mesh's half-edge structure, seams welded by position (``positions`` default: the rest positions)."""
    me = obj.data
    co = rest_positions(obj) if positions is None else positions
    return core_sym.Topology.from_loops(len(me.vertices), _read_int(me.loops, "vertex_index", 1),
                                        _read_int(me.polygons, "loop_start", 1),
                                        _read_int(me.polygons, "loop_total", 1), core_sym.weld_coincident(co))


def selected_edge(obj) -> int:
    """Index of the one selected edge (selection made in Edit Mode survives leaving it)."""
    sel = np.flatnonzero(_read_int(obj.data.edges, "select", 1))
    if sel.size != 1:
        raise ShapeSpaceError(f"select exactly one centre-line edge of {obj.name!r} in Edit Mode, then leave Edit "
                              f"Mode ({sel.size} edges are selected)", ErrorCode.CENTRE_EDGE)
    return int(sel[0])


def build_map(obj, method: str = "AUTO", axis: str = "X", centre: str = "ORIGIN", tolerance: float = None,
              edge: int = -1) -> core_sym.MirrorMap:
    """Compute (do not store) a mirror map of ``obj``'s mesh.

    ``method``: POSITION, TOPOLOGY (from ``edge``, or the one selected edge when ``edge < 0``; vertices the
    walk cannot reach are then paired by position) or AUTO (position, improved by topology from centre edges
    found on the plane when that leaves vertices unmapped).  ``centre``: ORIGIN (the plane through the object
    origin) or BOUNDS (through the middle of the bounding box).
    """
    if method not in METHODS:
        raise ShapeSpaceError(f"method must be one of {', '.join(METHODS)}, got {method!r}", ErrorCode.METHOD)
    tol = core_sym.DEFAULT_TOLERANCE if tolerance is None else tolerance
    co = rest_positions(obj)
    if not len(co):
        raise ShapeSpaceError(f"mesh {obj.name!r} has no vertices", ErrorCode.TOO_FEW)
    ax = core_sym.AXES.get(axis, axis)
    offset = 0.0 if centre == "ORIGIN" else None
    if method == "POSITION":
        return core_sym.position_map(co, ax, offset, tol)
    if offset is None:
        offset = float(0.5 * (co[:, ax].min() + co[:, ax].max()))
    topo = topology(obj, co)
    if method == "AUTO":
        return core_sym.auto_map(co, topo, ax, offset, tol)
    index = selected_edge(obj) if edge < 0 else int(edge)
    if not 0 <= index < len(obj.data.edges):
        raise ShapeSpaceError(f"edge {index} is not an edge of {obj.name!r} (it has {len(obj.data.edges)})",
                              ErrorCode.CENTRE_EDGE)
    a, b = obj.data.edges[index].vertices
    return core_sym.fill_by_position(core_sym.topology_map(topo, (a, b), ax, offset), co, tol)


def store_map(obj, mmap: core_sym.MirrorMap) -> None:
    """Write ``mmap`` on the mesh (replacing a stored map) with the mesh's topology fingerprint."""
    if len(mmap.mirror) != len(obj.data.vertices):
        raise ShapeSpaceError(f"the map has {len(mmap.mirror)} vertices, {obj.name!r} has "
                              f"{len(obj.data.vertices)}", ErrorCode.STALE_MIRROR_MAP)
    data = {"mirror": mmap.mirror.tolist(), "axis": int(mmap.axis), "offset": float(mmap.offset),
            "method": mmap.method, "tolerance": float(mmap.diagnostics.get("tolerance", 0.0)),
            "topology": fingerprint(obj.data), "coverage": mmap.coverage,
            "centre_edge": mmap.diagnostics.get("centre_edge")}
    storage.write_id_blob(obj.data, PROP, SCHEMA, data)


def has_map(obj) -> bool:
    return obj is not None and obj.type == "MESH" and PROP in obj.data


def _blob(obj) -> dict:
    data = storage.read_id_blob(obj.data, PROP, SCHEMA)
    if not data.get("mirror") and len(obj.data.vertices):
        raise ShapeSpaceError(f"{obj.name!r} has no mirror map: build one (Rig ▸ Symmetry ▸ Build Mirror Map)",
                              ErrorCode.NO_MIRROR_MAP)
    return data


def _stale_reason(stored: dict, now: dict) -> str | None:
    if stored == now:
        return None
    for k in ("vertices", "edges", "faces"):
        if stored.get(k) != now[k]:
            return f"built for {stored.get(k)} {k}, the mesh now has {now[k]}"
    return "the edge list changed since it was built"


def map_status(obj) -> dict:
    """``{"state": "none" | "ok" | "stale" | "damaged", "coverage": float, "method": str, "message": str}``
    (for the panel; never raises)."""
    if not has_map(obj):
        return {"state": "none", "coverage": 0.0, "method": "", "message": "No mirror map"}
    try:
        data = _blob(obj)
    except ShapeSpaceError as exc:
        return {"state": "damaged", "coverage": 0.0, "method": "", "message": str(exc)}
    reason = _stale_reason(data["topology"], fingerprint(obj.data))
    if reason:
        return {"state": "stale", "coverage": data["coverage"], "method": data["method"],
                "message": f"Mirror map is stale ({reason})"}
    return {"state": "ok", "coverage": data["coverage"], "method": data["method"],
            "message": f"Mirror map: {100 * data['coverage']:.2f} % mapped ({data['method']})"}


def load_map(obj) -> core_sym.MirrorMap:
    """The stored map, checked against the mesh's topology.

    Raises
    ------
    ShapeSpaceError
        ``no_mirror_map`` when none is stored, ``stale_mirror_map`` when the topology changed since it was built,
        ``corrupt_metadata`` when the blob is damaged.
    """
    if not has_map(obj):
        raise ShapeSpaceError(f"{obj.name!r} has no mirror map: build one (Rig ▸ Symmetry ▸ Build Mirror Map)",
                              ErrorCode.NO_MIRROR_MAP)
    data = _blob(obj)
    reason = _stale_reason(data["topology"], fingerprint(obj.data))
    if reason:
        raise ShapeSpaceError(f"the mirror map of {obj.name!r} is stale ({reason}): rebuild it with Build Mirror "
                              "Map", ErrorCode.STALE_MIRROR_MAP)
    where = storage.where(obj.data, PROP)
    try:
        mirror = np.asarray(data["mirror"], dtype=np.int64)
    except (TypeError, ValueError):
        raise ShapeSpaceError(f"damaged ShapeSpace data in {where}: mirror must be whole numbers",
                              ErrorCode.CORRUPT_METADATA) from None
    p = len(obj.data.vertices)
    ok = mirror >= 0
    if mirror.shape != (p,) or mirror.max(initial=-1) >= p or mirror.min(initial=0) < -1 \
            or not np.array_equal(mirror[mirror[ok]], np.flatnonzero(ok)) or not 0 <= data["axis"] <= 2:
        raise ShapeSpaceError(f"damaged ShapeSpace data in {where}: not a mirror table of {p} vertices",
                              ErrorCode.CORRUPT_METADATA)
    diag = {"tolerance": data["tolerance"]}
    if data.get("centre_edge"):
        diag["centre_edge"] = data["centre_edge"]
    return core_sym._finish(mirror, data["axis"], float(data["offset"]), data["method"], diag)


def table_damage(obj) -> list:
    """``core.Issue`` errors (code ``corrupt_metadata``) when ``obj``'s stored map reads but is no mirror table of
    its vertices (for Check Rig; a stale map is not damage, and a blob that does not read at all is
    :func:`bridge.storage.damaged_blobs`'s finding)."""
    if not has_map(obj) or storage.damaged_blobs(obj, (blobs.MIRROR_MAP,)):
        return []
    try:
        load_map(obj)
    except ShapeSpaceError as exc:
        if exc.code == ErrorCode.CORRUPT_METADATA:
            return [Issue("error", "corrupt_metadata", str(exc))]
        if exc.code == ErrorCode.NO_MIRROR_MAP:          # the blob reads but holds no table
            return [Issue("error", "corrupt_metadata",
                          f"damaged ShapeSpace data in {storage.where(obj.data, PROP)}: {exc}")]
    return []


def map_for(obj) -> tuple:
    """``(map, stored)``: the stored map when there is one (stale or damaged ones raise), else an AUTO map
    through the object origin computed now and not stored (refused when it maps less than half the mesh: the
    artist must choose the plane or a centre edge with Build Mirror Map)."""
    if has_map(obj):
        return load_map(obj), True
    mmap = build_map(obj, "AUTO")
    if mmap.coverage < 0.5:
        raise ShapeSpaceError(f"{obj.name!r} is not symmetric across its local X = 0 plane ({mmap.coverage:.0%} "
                              "of the vertices have a mirror): build a mirror map first (Rig ▸ Symmetry ▸ Build "
                              "Mirror Map: Bounding-Box Centre plane, or Topology from a centre edge)",
                              ErrorCode.NO_MIRROR_MAP)
    return mmap, False


# -- shape keys ------------------------------------------------------------------------------------------------

def _key(obj, name: str):
    if not len(obj.data.vertices):
        raise ShapeSpaceError(f"mesh {obj.name!r} has no vertices", ErrorCode.TOO_FEW)
    key = obj.data.shape_keys
    if key is None or name not in key.key_blocks:
        raise ShapeSpaceError(f"{obj.name!r} has no shape key {name!r}", ErrorCode.MISSING_KEY)
    kb = key.key_blocks[name]
    if kb == key.reference_key:
        raise ShapeSpaceError(f"{name!r} is the basis key of {obj.name!r}: pick a shape", ErrorCode.MISSING_KEY)
    return kb


def _coords(obj, kb) -> np.ndarray:
    return coordinates(read_float(kb.points, "co", 3).astype(np.float64), f"shape key {kb.name!r} of {obj.name!r}")


def key_delta(obj, name: str) -> np.ndarray:
    """The key's effective delta (key − its relative key, times its vertex-group mask), float64 (p, 3)."""
    kb = _key(obj, name)
    key = obj.data.shape_keys
    rel = kb.relative_key if kb.relative_key is not None else key.reference_key
    if rel == kb:
        return np.zeros((len(obj.data.vertices), 3))
    d = _coords(obj, kb) - _coords(obj, rel)
    if kb.vertex_group:
        mask = group_weight_vector(obj, kb.vertex_group)
        if mask is not None:
            d = d * mask[:, None]
    return d


def _check_new(obj, names) -> None:
    existing = [n for n in names if n in obj.data.shape_keys.key_blocks]
    if existing:
        raise ShapeSpaceError(f"{obj.name!r} already has a shape key {existing[0]!r}: rename or delete it first "
                              "(nothing was changed)", ErrorCode.DUPLICATE_NAME)


def _new_key(obj, name: str, delta: np.ndarray, like) -> str:
    """A key ``basis + delta`` relative to the basis, with ``like``'s slider range (written in one go)."""
    key = obj.data.shape_keys
    base = read_float(key.reference_key.points, "co", 3).astype(np.float64)
    kb = obj.shape_key_add(name=name, from_mix=False)
    write_float(kb.points, "co", base + delta)
    kb.relative_key = key.reference_key
    kb.slider_min, kb.slider_max = like.slider_min, like.slider_max
    return kb.name


def _set_delta(obj, kb, delta: np.ndarray) -> None:
    """Rewrite ``kb`` so its delta to its relative key is ``delta`` (its own vertex-group mask is cleared when the
    baked delta already holds the mask)."""
    key = obj.data.shape_keys
    rel = kb.relative_key if kb.relative_key is not None and kb.relative_key != kb else key.reference_key
    write_float(kb.points, "co", read_float(rel.points, "co", 3).astype(np.float64) + delta)


def _finite(obj, arr: np.ndarray, what: str) -> None:
    if not np.isfinite(arr).all():
        raise ShapeSpaceError(f"refusing to write non-finite coordinates into {what} of {obj.name!r}",
                              ErrorCode.NON_FINITE)


def _mirrored(obj, name: str, mmap: core_sym.MirrorMap):
    """:func:`core.symmetry.mirror_delta` of key ``name``, vertices without a mirror filled from the mirrored
    rest surface (the core Result says how many)."""
    return core_sym.mirror_delta(key_delta(obj, name), mmap, rest_positions(obj), triangles(obj.data))


def mirror_shape(obj, name: str, mmap: core_sym.MirrorMap) -> tuple:
    """Create the mirrored key of ``name`` (``browDown_L`` → ``browDown_R``, else ``<name>_mirror``).

    Returns ``(new name, core Result of the mirror)``.  Refuses when that key already exists (Update Mirrored
    rewrites an existing one).
    """
    src = _key(obj, name)
    target = core_sym.counterpart_name(name) or f"{name}_mirror"
    _check_new(obj, [target])
    res = _mirrored(obj, name, mmap)
    _finite(obj, res.value, f"shape key {target!r}")
    made = _new_key(obj, target, res.value, src)
    obj.data.update()
    return made, res


def split_shape(obj, name: str, mmap: core_sym.MirrorMap, falloff: float = 0.05) -> tuple:
    """Split ``name`` into ``<name>_L`` and ``<name>_R`` (``Δ_L = w_L Δ``, ``Δ_R = Δ − Δ_L``).

    The halves take the original's value and slider range and the original is muted (kept, never deleted), so
    the mesh looks exactly as before.  Returns ``(left, right)``.
    """
    src = _key(obj, name)
    left_name, right_name = core_sym.side_names(name)
    _check_new(obj, [left_name, right_name])
    in_range(falloff, "falloff (a fraction of the mesh's size)", 0.0, 1.0)
    w = core_sym.split_weights(rest_positions(obj), mmap.axis, mmap.offset, falloff)
    left, right = core_sym.split_delta(key_delta(obj, name), w)
    _finite(obj, left, "the split keys")
    value = src.value
    made = (_new_key(obj, left_name, left, src), _new_key(obj, right_name, right, src))
    blocks = obj.data.shape_keys.key_blocks
    for n in made:
        blocks[n].value = value
    src.mute = True
    obj.data.update()
    return made


def combine_shapes(obj, left: str, right: str, name: str = "") -> str:
    """Create ``name`` (default: ``left`` without its side) holding ``Δ_L + Δ_R``, at value 0; the halves are kept
    as they are (the mesh looks as before)."""
    a, b = _key(obj, left), _key(obj, right)
    target = name or core_sym.whole_name(left) or f"{left}_{right}"
    _check_new(obj, [target])
    whole = core_sym.combine_deltas(key_delta(obj, left), key_delta(obj, right))
    _finite(obj, whole, f"shape key {target!r}")
    made = _new_key(obj, target, whole, a)
    obj.data.shape_keys.key_blocks[made].slider_min = min(a.slider_min, b.slider_min)
    obj.data.shape_keys.key_blocks[made].slider_max = max(a.slider_max, b.slider_max)
    obj.data.shape_keys.key_blocks[made].value = 0.0
    obj.data.update()
    return made


def update_mirrored(obj, name: str, mmap: core_sym.MirrorMap, source: str = "LEFT") -> tuple:
    """Push a sculpted key onto its mirror.

    A side-named key (``browDown_L``) rewrites its counterpart (``browDown_R``) as the mirror of ``name``'s delta
    and is refused, naming the counterpart, when that does not exist (Mirror Shape creates it); a key without a
    side in its name is a middle shape: its ``source`` side (LEFT = +axis) is mirrored onto its other side.
    Returns ``(the key that was rewritten, core Result)``.
    """
    src = _key(obj, name)
    other = core_sym.counterpart_name(name)
    blocks = obj.data.shape_keys.key_blocks
    if other is not None and other not in blocks:
        raise ShapeSpaceError(f"{name!r} is a one-side shape but {obj.name!r} has no {other!r} to update: Mirror "
                              f"Shape creates it (nothing was changed)", ErrorCode.MISSING_KEY)
    if other is not None:
        kb = _key(obj, other)
        res = _mirrored(obj, name, mmap)
    else:
        kb = src
        res = core_sym.symmetrize_delta(key_delta(obj, name), mmap, rest_positions(obj), source)
    _finite(obj, res.value, f"shape key {kb.name!r}")
    mask_group = kb.vertex_group
    _set_delta(obj, kb, res.value)
    if mask_group:
        kb.vertex_group = ""            # the written delta is final: a mask would scale it again
    obj.data.update()
    return kb.name, res
