"""Left↔right symmetry of a mesh: the mirror map, and mirroring, splitting and combining shape deltas.

A *mirror map* pairs every vertex v with its mirror vertex m(v) (an involution: m(m(v)) = v; a vertex on the
centre line is its own mirror).  It is found

- **by position** (:func:`position_map`): v's mirror is the vertex nearest to the reflection of v across the
  plane ``x_axis = offset`` (KD-tree), accepted within a tolerance relative to the bounding-box diagonal and
  made one-to-one (coincident seam vertices are paired, never shared);
- **by topology** (:func:`topology_map`), for a mesh that is not symmetric in space (posed, sculpted
  asymmetrically): Maya's *symmetry edge*.  From a chosen centre-line edge, whose two faces are mirror
  images, the faces are walked breadth-first over the half-edge structure, each face pair walked in opposite
  winding, so corresponding vertices come out pairwise;
- combined (:func:`fill_by_position`): vertices the topological walk did not reach (separate parts such as
  eyes or teeth, cut seams) are paired by position.

Operations on shape deltas ``Δ`` (p, 3), with ``R`` the reflection that negates the ``axis`` component:

- mirror: ``Δ'[v] = R Δ[m(v)]`` (:func:`mirror_delta`; applying it twice gives Δ back on mapped vertices);
- split: ``Δ_L = w_L Δ``, ``Δ_R = Δ − Δ_L`` with a smooth falloff ``w_L`` across the centre plane, so
  ``Δ_L + Δ_R = Δ`` to float precision (:func:`split_delta`, :func:`combine_deltas`);
- symmetrize: one side's sculpt pushed onto the other side (:func:`symmetrize_delta`).

"Left" is the character's left, the +axis side (Blender's ``.L`` convention, the character facing −Y).
"""
from __future__ import annotations

import hashlib
from collections import deque
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree

from . import validate
from .errors import ErrorCode
from .result import Result, ShapeSpaceError, Status
from .surface import closest_on_triangles

__all__ = ["MirrorMap", "Topology", "position_map", "topology_map", "fill_by_position", "find_centre_edges",
           "auto_map", "weld_coincident", "mirror_delta", "split_weights", "split_delta", "combine_deltas",
           "symmetrize_delta", "topology_fingerprint", "counterpart_name", "side_names", "whole_name", "AXES"]

#: Axis name → index.
AXES = {"X": 0, "Y": 1, "Z": 2}

#: Default position tolerance, as a fraction of the bounding-box diagonal (0.3 mm on a 30 cm head).
DEFAULT_TOLERANCE = 1e-3


@dataclass(kw_only=True)
class MirrorMap(Result):
    """A vertex ↔ mirror-vertex table (``value`` is :attr:`mirror`).

    Attributes
    ----------
    value : ndarray of int64, shape (p,)
        ``mirror[v]`` is v's mirror vertex, ``-1`` where v has none.  ``mirror[mirror[v]] == v`` wherever
        ``mirror[v] >= 0``.
    axis : int
        0, 1, 2 for X, Y, Z: the axis the mirror plane is perpendicular to.
    offset : float
        The plane is ``x_axis = offset`` (object space).
    method : str
        ``"position"``, ``"topology"`` or ``"topology+position"``.
    status : Status
        OK when every vertex is mapped, WARNING otherwise (``message`` says how many are not).
    """

    axis: int = 0
    offset: float = 0.0
    method: str = "position"

    @property
    def mirror(self) -> np.ndarray:
        """(p,) int64, −1 where unmapped."""
        return self.value

    @property
    def centre(self) -> np.ndarray:
        """(p,) bool: vertices that are their own mirror (on the centre line)."""
        return self.value == np.arange(len(self.value))

    @property
    def unmapped(self) -> np.ndarray:
        """Indices of the vertices without a mirror, int64 (u,)."""
        return np.flatnonzero(self.value < 0)

    @property
    def coverage(self) -> float:
        """Fraction of vertices with a mirror (1.0 for an empty mesh)."""
        return float(np.mean(self.value >= 0)) if len(self.value) else 1.0


def _finish(mirror: np.ndarray, axis: int, offset: float, method: str, diagnostics: dict) -> MirrorMap:
    p = len(mirror)
    unmapped = int(np.sum(mirror < 0))
    diagnostics = dict(diagnostics, unmapped=unmapped, centre=int(np.sum(mirror == np.arange(p))))
    if unmapped:
        first = np.flatnonzero(mirror < 0)[:5].tolist()
        return MirrorMap(mirror, axis=axis, offset=offset, method=method, status=Status.WARNING,
                         message=f"{unmapped} of {p} vertices have no mirror (first: {first})",
                         diagnostics=diagnostics)
    return MirrorMap(mirror, axis=axis, offset=offset, method=method,
                     message=f"all {p} vertices mapped ({diagnostics['centre']} on the centre line)",
                     diagnostics=diagnostics)


def _axis(axis) -> int:
    if isinstance(axis, str):
        key = axis.upper()
        if key not in AXES:
            raise ShapeSpaceError(f"axis must be one of X, Y, Z, got {axis!r}", ErrorCode.RANGE)
        return AXES[key]
    if isinstance(axis, (bool, np.bool_)) or not isinstance(axis, (int, np.integer)) or not 0 <= int(axis) <= 2:
        raise ShapeSpaceError(f"axis must be 0, 1, 2 or 'X', 'Y', 'Z', got {axis!r}", ErrorCode.RANGE)
    return int(axis)


def _diagonal(co: np.ndarray) -> float:
    return float(np.linalg.norm(np.ptp(co, axis=0))) if len(co) else 0.0


def _reflect(co: np.ndarray, axis: int, offset: float) -> np.ndarray:
    out = co.copy()
    out[:, axis] = 2.0 * offset - out[:, axis]
    return out


def _match_pairs(cand_v: np.ndarray, cand_w: np.ndarray, cand_d: np.ndarray, p: int) -> np.ndarray:
    """Symmetric one-to-one pairing from candidate pairs (v, w, distance): closest first, self-pairs win ties."""
    mirror = np.full(p, -1, dtype=np.int64)
    order = np.lexsort((cand_v != cand_w, cand_d))
    for v, w in zip(cand_v[order].tolist(), cand_w[order].tolist()):
        if mirror[v] < 0 and mirror[w] < 0:
            mirror[v] = w
            mirror[w] = v
    return mirror


def _position_pairs(co: np.ndarray, subset: np.ndarray, axis: int, offset: float, tol: float, k: int = 4):
    """Candidate pairs among ``subset``: (v, w, distance) with w near the reflection of v, within ``tol``."""
    if len(subset) == 0:
        return (np.zeros(0, np.int64),) * 2 + (np.zeros(0),)
    pts = co[subset]
    k = min(k, len(subset))
    dist, idx = cKDTree(pts).query(_reflect(pts, axis, offset), k=k, distance_upper_bound=tol if tol > 0 else 0.0)
    dist = dist.reshape(len(subset), k)
    idx = idx.reshape(len(subset), k)
    ok = np.isfinite(dist) & (dist <= tol)
    rows = np.repeat(np.arange(len(subset)), k).reshape(len(subset), k)
    return subset[rows[ok]], subset[idx[ok]], dist[ok]


def position_map(positions: ArrayLike, axis: int | str = 0, offset: float | None = 0.0,
                 tolerance: float = DEFAULT_TOLERANCE) -> MirrorMap:
    """Mirror map by position: each vertex paired with the vertex at its reflection across a plane.

    For every vertex v the KD-tree gives the vertices near ``R v`` (the reflection across
    ``x_axis = offset``); pairs within ``tolerance · diag`` are accepted closest first, each vertex at most once,
    and always both ways (``m(m(v)) = v``), so coincident seam vertices get distinct partners.

    Parameters
    ----------
    positions : array_like, shape (p, 3)
        Rest positions in object space.
    axis : int or {"X", "Y", "Z"}
        The axis perpendicular to the mirror plane (X by default).
    offset : float or None
        Where the plane crosses the axis; ``None`` uses the middle of the bounding box along ``axis``
        (a head modelled off-centre).
    tolerance : float
        Largest accepted distance between ``R v`` and its partner, as a fraction of the bounding-box diagonal.

    Returns
    -------
    MirrorMap
        WARNING status (and the unmapped indices) when some vertex has no partner.
    """
    co = validate.array(positions, "positions", shape=(None, 3))
    ax = _axis(axis)
    tolerance = validate.non_negative(tolerance, "tolerance")
    if offset is None:
        offset = float(0.5 * (co[:, ax].min() + co[:, ax].max())) if len(co) else 0.0
    offset = validate.finite_scalar(offset, "offset")
    diag = _diagonal(co) or 1.0
    v, w, d = _position_pairs(co, np.arange(len(co)), ax, offset, tolerance * diag)
    mirror = _match_pairs(v, w, d, len(co))
    return _finish(mirror, ax, offset, "position", {"tolerance": tolerance * diag})


@dataclass(frozen=True)
class Topology:
    """A polygon mesh's half-edge structure (one half-edge per face corner, Blender's loop layout).

    Attributes
    ----------
    n_vertices : int
    origin, dest : ndarray of int64, shape (h,)
        Half-edge h runs from ``origin[h]`` to ``dest[h]``.
    face : ndarray of int64, shape (h,)
    next, prev : ndarray of int64, shape (h,)
        The following / preceding half-edge in the same face.
    twin : ndarray of int64, shape (h,)
        The opposite half-edge of the neighbouring face, −1 on a boundary or non-manifold edge.
    """

    n_vertices: int
    origin: np.ndarray
    dest: np.ndarray
    face: np.ndarray
    next: np.ndarray
    prev: np.ndarray
    twin: np.ndarray

    @classmethod
    def from_loops(cls, n_vertices: int, loop_vertices: ArrayLike, loop_starts: ArrayLike,
                   loop_totals: ArrayLike, weld: ArrayLike | None = None) -> Topology:
        """Build from Blender's layout: ``loop_vertices`` (l,), per-face ``loop_starts`` and ``loop_totals`` (f,).

        ``weld`` (p,) optionally names each vertex's representative (:func:`weld_coincident`): faces meeting at
        a UV seam, whose vertices are split but coincident, then count as neighbours.
        """
        lv = np.asarray(loop_vertices, dtype=np.int64).ravel()
        ls = np.asarray(loop_starts, dtype=np.int64).ravel()
        lt = np.asarray(loop_totals, dtype=np.int64).ravel()
        if ls.shape != lt.shape:
            raise ShapeSpaceError(f"loop_starts {ls.shape} and loop_totals {lt.shape} differ", ErrorCode.SHAPE)
        if lv.size and (lv.min() < 0 or lv.max() >= n_vertices):
            raise ShapeSpaceError(f"a face corner names a vertex outside 0..{n_vertices - 1}", ErrorCode.RANGE)
        if np.any(lt < 3) or (ls.size and (ls.min() < 0 or (ls + lt).max() > lv.size)):
            raise ShapeSpaceError("faces must have at least 3 corners inside the loop array", ErrorCode.RANGE)
        face = np.repeat(np.arange(len(ls)), lt)
        corners = np.concatenate([np.arange(s, s + t) for s, t in zip(ls.tolist(), lt.tolist())]) \
            if len(ls) else np.zeros(0, np.int64)
        # half-edges are numbered by corner order within faces (h-th corner of the concatenation)
        first = np.repeat(np.cumsum(lt) - lt, lt)
        local = np.arange(len(face)) - first
        tot = lt[face]
        nxt = first + (local + 1) % tot
        prv = first + (local - 1) % tot
        origin = lv[corners]
        dest = origin[nxt]
        rep = np.arange(n_vertices, dtype=np.int64) if weld is None else np.asarray(weld, dtype=np.int64)
        if rep.shape != (n_vertices,):
            raise ShapeSpaceError(f"weld must have shape ({n_vertices},), got {rep.shape}", ErrorCode.SHAPE)
        wo, wd = rep[origin], rep[dest]
        key = wo * n_vertices + wd
        rev = wd * n_vertices + wo
        order = np.argsort(key, kind="stable")
        sk = key[order]
        dup = np.zeros(len(sk), bool)
        if len(sk) > 1:
            same = sk[1:] == sk[:-1]
            dup[1:] |= same
            dup[:-1] |= same
        pos = np.searchsorted(sk, rev)
        pos_c = np.minimum(pos, max(len(sk) - 1, 0))
        found = (len(sk) > 0) & (sk[pos_c] == rev) & ~dup[pos_c]
        twin = np.where(found, order[pos_c], -1)
        # an edge used twice in one direction is non-manifold (or the normals flip): no twin across it
        bad = np.zeros(len(key), bool)
        bad[order[dup]] = True
        twin[bad] = -1
        twin[(twin >= 0) & bad[np.maximum(twin, 0)]] = -1
        return cls(int(n_vertices), origin, dest, face, nxt, prv, twin)


def weld_coincident(positions: ArrayLike, tolerance: float = 1e-6) -> np.ndarray:
    """Each vertex's representative among the vertices at (almost) the same place: the lowest index.

    Parameters
    ----------
    positions : array_like, shape (p, 3)
    tolerance : float
        Distance below which two vertices are one, as a fraction of the bounding-box diagonal.

    Returns
    -------
    ndarray of int64, shape (p,)
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    co = validate.array(positions, "positions", shape=(None, 3))
    p = len(co)
    if p == 0:
        return np.zeros(0, np.int64)
    pairs = cKDTree(co).query_pairs(tolerance * (_diagonal(co) or 1.0), output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(p, p))
    _, label = connected_components(graph, directed=False)
    rep = np.full(label.max() + 1, p, dtype=np.int64)
    np.minimum.at(rep, label, np.arange(p))
    return rep[label]


def topology_map(topology: Topology, centre_edge: tuple, axis: int | str = 0, offset: float = 0.0) -> MirrorMap:
    """Mirror map by topology from a centre-line edge (Maya's symmetry edge).

    The centre edge (a, b) maps to itself (m(a) = a, m(b) = b) and its two faces to each other.  Each face pair
    is walked in opposite winding, half-edge ``h`` of one face with half-edge ``g`` of the other such that
    ``origin(g) = m(dest(h))``, ``dest(g) = m(origin(h))``; every matched pair's twins give the next face pair
    (breadth first).  A face pair of different sizes, or one that would give a vertex a second, different
    mirror, marks a topological asymmetry: it is skipped and the walk does not continue through it.  Only the
    seed's connected part is reached (weld seams with :func:`weld_coincident`).

    Parameters
    ----------
    topology : Topology
    centre_edge : tuple of two int
        The vertices of an edge on the centre line, with a face on each side.
    axis : int or {"X", "Y", "Z"}
        Recorded on the result (used by splitting); the walk itself does not use positions.
    offset : float
        Recorded on the result.

    Returns
    -------
    MirrorMap
        ``method="topology"``; WARNING when some vertex was not reached (or sat in a face pair that disagreed
        with the pairs already made: ``diagnostics["faces_mismatched"]``).

    Raises
    ------
    ShapeSpaceError
        Code ``centre_edge`` when (a, b) is not an edge or has no face on one side.
    """
    ax = _axis(axis)
    offset = validate.finite_scalar(offset, "offset")
    try:
        a, b = (int(i) for i in centre_edge)
    except (TypeError, ValueError):
        raise ShapeSpaceError(f"centre_edge must be two vertex indices, got {centre_edge!r}",
                              ErrorCode.CENTRE_EDGE) from None
    t = topology
    hits = np.flatnonzero((t.origin == a) & (t.dest == b))
    if not hits.size:
        hits = np.flatnonzero((t.origin == b) & (t.dest == a))
    if not hits.size:
        raise ShapeSpaceError(f"vertices {a} and {b} are not joined by an edge of a face", ErrorCode.CENTRE_EDGE)
    h0 = int(hits[0])
    g0 = int(t.twin[h0])
    if g0 < 0:
        raise ShapeSpaceError(f"the centre edge ({a}, {b}) has a face on one side only (a boundary or "
                              "non-manifold edge): pick an edge with a face on each side", ErrorCode.CENTRE_EDGE)
    mirror = np.full(t.n_vertices, -1, dtype=np.int64)
    face_done = np.zeros(int(t.face.max()) + 1 if len(t.face) else 0, bool)
    origin, dest, nxt, prv, twin, face = (x.tolist() for x in (t.origin, t.dest, t.next, t.prev, t.twin, t.face))
    mirror_l = mirror.tolist()
    sizes = np.bincount(t.face).tolist() if len(t.face) else []
    queue = deque([(h0, g0)])
    faces_walked = 0
    mismatched = 0

    while queue:
        h, g = queue.popleft()
        fh, fg = face[h], face[g]
        if face_done[fh] or face_done[fg]:
            continue
        if sizes[fh] != sizes[fg]:
            mismatched += 1
            continue
        pairs, hs, gs = [], [], []
        hh, gg = h, g
        for _ in range(sizes[fh]):
            pairs.append((origin[hh], dest[gg]))
            hs.append(hh)
            gs.append(gg)
            hh, gg = nxt[hh], prv[gg]
        # a face pair is accepted only when it agrees with every pair already made: an asymmetry stops the
        # walk there instead of spreading wrong pairs
        local = {}
        for u, w in pairs:
            local.setdefault(u, w)
            local.setdefault(w, u)
        if any(local[u] != w or local[w] != u or (mirror_l[u] >= 0 and mirror_l[u] != w)
               or (mirror_l[w] >= 0 and mirror_l[w] != u) for u, w in pairs):
            mismatched += 1
            continue
        face_done[fh] = face_done[fg] = True
        faces_walked += 1
        for u, w in pairs:
            mirror_l[u] = w
            mirror_l[w] = u
        for hh, gg in zip(hs, gs):
            th, tg = twin[hh], twin[gg]
            if th >= 0 and tg >= 0 and not (face_done[face[th]] or face_done[face[tg]]):
                queue.append((th, tg))
    mirror = np.asarray(mirror_l, dtype=np.int64)
    return _finish(mirror, ax, offset, "topology",
                   {"faces_walked": faces_walked, "faces_mismatched": mismatched,
                    "centre_edge": [a, b]})


def fill_by_position(mmap: MirrorMap, positions: ArrayLike, tolerance: float = DEFAULT_TOLERANCE) -> MirrorMap:
    """Pair the vertices a map left unmapped by position (among themselves), keeping every existing pair.

    Parameters
    ----------
    mmap : MirrorMap
        Usually from :func:`topology_map` (whose walk cannot cross to separate parts).
    positions : array_like, shape (p, 3)
    tolerance : float
        As in :func:`position_map`.

    Returns
    -------
    MirrorMap
        ``method`` gains ``"+position"`` when some vertex was added.
    """
    co = validate.array(positions, "positions", shape=(len(mmap.mirror), 3))
    tolerance = validate.non_negative(tolerance, "tolerance")
    mirror = mmap.mirror.copy()
    free = np.flatnonzero(mirror < 0)
    v, w, d = _position_pairs(co, free, mmap.axis, mmap.offset, tolerance * (_diagonal(co) or 1.0))
    sub = _match_pairs(v, w, d, len(co))
    added = int(np.sum(sub[free] >= 0))
    mirror[free] = np.where(sub[free] >= 0, sub[free], -1)
    method = mmap.method + ("+position" if added and "position" not in mmap.method else "")
    return _finish(mirror, mmap.axis, mmap.offset, method, dict(mmap.diagnostics, filled_by_position=added))


def find_centre_edges(positions: ArrayLike, topology: Topology, axis: int | str = 0, offset: float = 0.0,
                      tolerance: float = DEFAULT_TOLERANCE, limit: int = 8) -> np.ndarray:
    """Candidate centre edges: interior edges with both ends on the plane, whose two faces lie on opposite sides.

    Parameters
    ----------
    positions : array_like, shape (p, 3)
    topology : Topology
    axis, offset, tolerance
        As in :func:`position_map`.
    limit : int
        At most this many edges, spread over the centre line.

    Returns
    -------
    ndarray of int64, shape (k, 2)
        Vertex pairs (a, b).
    """
    co = validate.array(positions, "positions", shape=(topology.n_vertices, 3))
    ax = _axis(axis)
    tol = tolerance * (_diagonal(co) or 1.0)
    t = topology
    s = co[:, ax] - offset
    on = np.abs(s) <= tol
    cand = np.flatnonzero(on[t.origin] & on[t.dest] & (t.twin >= 0) & (t.origin < t.dest))
    if not cand.size:
        return np.zeros((0, 2), np.int64)
    nf = int(t.face.max()) + 1
    fc = np.zeros(nf)
    np.add.at(fc, t.face, s[t.origin])
    fc /= np.bincount(t.face, minlength=nf)
    side_a = fc[t.face[cand]]
    side_b = fc[t.face[t.twin[cand]]]
    cand = cand[(side_a * side_b) < 0]
    if not cand.size:
        return np.zeros((0, 2), np.int64)
    pick = cand[np.linspace(0, len(cand) - 1, min(limit, len(cand))).round().astype(np.int64)]
    return np.stack([t.origin[pick], t.dest[pick]], axis=1)


def auto_map(positions: ArrayLike, topology: Topology | None = None, axis: int | str = 0, offset: float | None = 0.0,
             tolerance: float = DEFAULT_TOLERANCE) -> MirrorMap:
    """The best map without an artist's centre edge: by position, and when that leaves vertices unmapped and the
    faces are known, by topology from the centre edges found on the plane, filled by position.

    Parameters
    ----------
    positions : array_like, shape (p, 3)
    topology : Topology or None
    axis, offset, tolerance
        As in :func:`position_map`.

    Returns
    -------
    MirrorMap
        The candidate with the highest coverage (position wins ties).
    """
    best = position_map(positions, axis, offset, tolerance)
    if best.coverage == 1.0 or topology is None:
        return best
    co = np.asarray(positions, dtype=np.float64)
    for a, b in find_centre_edges(co, topology, best.axis, best.offset, tolerance).tolist():
        try:
            cand = fill_by_position(topology_map(topology, (a, b), best.axis, best.offset), co, tolerance)
        except ShapeSpaceError:
            continue
        if cand.coverage > best.coverage:
            best = cand
    return best


def _check_map(delta: np.ndarray, mmap: MirrorMap) -> np.ndarray:
    mirror = np.asarray(mmap.mirror, dtype=np.int64)
    if mirror.shape != (delta.shape[0],):
        raise ShapeSpaceError(f"the mirror map has {mirror.shape[0]} vertices but the delta has {delta.shape[0]}",
                              ErrorCode.STALE_MIRROR_MAP)
    return mirror


#: How far from the rest mesh (a fraction of its bounding-box diagonal: 3 mm on a 30 cm head) the reflection of a
#: vertex without a mirror may lie for it to take the mirrored surface's motion; further, nothing is invented.
FILL_DISTANCE = 0.01


def mirror_delta(delta: ArrayLike, mmap: MirrorMap, positions: ArrayLike = None, triangles: ArrayLike = None) -> Result:
    """The mirrored shape delta: ``Δ'[v] = R Δ[m(v)]``, R negating the ``axis`` component.

    With the rest ``positions`` (and ``triangles``), a vertex the map could not pair takes the mirrored motion of
    the mesh at its reflected position: ``Δ'[v] = R Σ b_i Δ[t_i]`` with ``t`` the triangle closest to the
    reflection of ``positions[v]`` and ``b`` the barycentric coordinates of that closest point (the rule the map
    follows, ``x[m(v)] ≈ reflection of x[v]``, continued between vertices; a vertex in no triangle counts as a
    point of the mesh), when that point lies within :data:`FILL_DISTANCE` of the mesh.

    Parameters
    ----------
    delta : array_like, shape (p, 3)
        Shape minus basis, object space.
    mmap : MirrorMap
    positions : array_like, shape (p, 3), optional
        Rest positions (object space): fill vertices without a mirror.
    triangles : array_like of int, shape (f, 3), optional
        The rest mesh's triangles (without them only its vertices are the mesh).

    Returns
    -------
    Result
        ``value`` (p, 3) float64; zero on unmapped vertices that were not filled.  WARNING when vertices were
        filled (``diagnostics["filled"]``, their count in the message) or when an unmapped vertex that moves was
        not (``diagnostics["lost_vertices"]``): that part of the shape is not mirrored.
    """
    d = validate.array(delta, "delta", shape=(None, 3))
    mirror = _check_map(d, mmap)
    ok = mirror >= 0
    out = np.zeros_like(d)
    out[ok] = d[mirror[ok]]
    unmapped = np.flatnonzero(~ok)
    filled = np.zeros(0, dtype=np.int64)
    if positions is not None and unmapped.size:
        motion, near = _surface_motion(d, mmap, positions, triangles, unmapped)
        filled = unmapped[near]
        out[filled] = motion[near]
    out[:, mmap.axis] *= -1.0
    moving = np.linalg.norm(d, axis=1) > 0
    lost = np.setdiff1d(np.flatnonzero(~ok & moving), filled)
    notes = []
    if filled.size:
        notes.append(f"{filled.size} vertices without a mirror took the mirrored surface's motion at their "
                     "reflected position")
    if lost.size:
        notes.append(f"{lost.size} moving vertices have no mirror (first: {lost[:5].tolist()}): their motion is not "
                     "mirrored")
    return Result(out, status=Status.WARNING if notes else Status.OK, message="; ".join(notes),
                  diagnostics={"lost_vertices": lost.tolist(), "filled": filled.tolist()})


def _surface_motion(delta: np.ndarray, mmap: MirrorMap, positions: ArrayLike, triangles, vertices: np.ndarray):
    """``delta`` at the points of the rest mesh closest to the reflections of ``vertices`` (u,): barycentric on
    the closest triangle, or a vertex's own when a vertex (one in no triangle) is closer.  Returns the motion
    (u, 3), unreflected, and whether that point lies within :data:`FILL_DISTANCE` (u,) bool."""
    co = validate.array(positions, "positions", shape=delta.shape)
    tris = np.zeros((0, 3), np.int64) if triangles is None else np.asarray(triangles, np.int64).reshape(-1, 3)
    if len(tris) and (tris.min() < 0 or tris.max() >= len(co)):
        raise ShapeSpaceError(f"the triangles do not index the {len(co)} vertices", ErrorCode.STALE_MIRROR_MAP)
    query = _reflect(co[vertices], mmap.axis, mmap.offset)
    dist, nearest = cKDTree(co).query(query)
    motion = delta[nearest]
    if len(tris):
        tri, bary, _, tri_dist = closest_on_triangles(query, co, tris)
        on_tri = tri_dist < dist
        motion[on_tri] = np.einsum("uk,ukj->uj", bary[on_tri], delta[tris[tri[on_tri]]])
        dist = np.minimum(dist, tri_dist)
    return motion, dist <= FILL_DISTANCE * _diagonal(co)


def split_weights(positions: ArrayLike, axis: int | str = 0, offset: float = 0.0, falloff: float = 0.05) -> np.ndarray:
    """Left weight per vertex: 1 on the left (+axis) side, 0 on the right, smoothstep across the centre.

    ``w_L = S((s + f/2) / f)`` with ``s`` the signed distance to the plane, ``f = falloff · diag`` the width
    of the blend band and ``S(t) = 3t² − 2t³`` clamped to [0, 1]; ``falloff = 0`` gives a hard split with
    weight ½ on the plane.

    Parameters
    ----------
    positions : array_like, shape (p, 3)
        Rest positions, object space.
    axis, offset
        The mirror plane.
    falloff : float
        Width of the blend band as a fraction of the bounding-box diagonal.

    Returns
    -------
    ndarray, shape (p,)
        In [0, 1]; the right weight is ``1 − w_L``.
    """
    co = validate.array(positions, "positions", shape=(None, 3))
    ax = _axis(axis)
    offset = validate.finite_scalar(offset, "offset")
    falloff = validate.non_negative(falloff, "falloff")
    s = co[:, ax] - offset
    width = falloff * _diagonal(co)
    if width <= 0:
        return np.where(s > 0, 1.0, np.where(s < 0, 0.0, 0.5))
    t = np.clip((s + 0.5 * width) / width, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def split_delta(delta: ArrayLike, weights_left: ArrayLike) -> tuple:
    """Split a delta into left and right halves that add up to it: ``Δ_L = w_L Δ``, ``Δ_R = Δ − Δ_L``.

    Parameters
    ----------
    delta : array_like, shape (p, 3)
    weights_left : array_like, shape (p,)
        From :func:`split_weights` (any values in [0, 1]).

    Returns
    -------
    left, right : ndarray, shape (p, 3)
        ``left + right == delta`` up to one rounding of the subtraction.
    """
    d = validate.array(delta, "delta", shape=(None, 3))
    w = validate.array(weights_left, "weights_left", shape=(d.shape[0],))
    if w.size and (w.min() < 0 or w.max() > 1):
        raise ShapeSpaceError("weights_left must lie in [0, 1]", ErrorCode.RANGE)
    left = d * w[:, None]
    return left, d - left


def combine_deltas(left: ArrayLike, right: ArrayLike) -> np.ndarray:
    """The whole shape from its halves: ``Δ = Δ_L + Δ_R``.

    Parameters
    ----------
    left, right : array_like, shape (p, 3)

    Returns
    -------
    ndarray, shape (p, 3)
    """
    a = validate.array(left, "left", shape=(None, 3))
    b = validate.array(right, "right", shape=a.shape)
    return a + b


def symmetrize_delta(delta: ArrayLike, mmap: MirrorMap, positions: ArrayLike, source: str = "LEFT") -> Result:
    """Push one side's sculpt onto the other side of the same shape.

    Vertices on the ``source`` side keep their delta, vertices on the other side take the mirror of their
    partner's (``R Δ[m(v)]``) and centre vertices the symmetric part ``(Δ + R Δ) / 2``, so the result ``Δ_s``
    satisfies ``Δ_s = mirror(Δ_s)`` on mapped vertices.

    Parameters
    ----------
    delta : array_like, shape (p, 3)
    mmap : MirrorMap
    positions : array_like, shape (p, 3)
        Rest positions (decide each vertex's side: sign of ``x_axis − offset``; a vertex mapped to itself is
        on the centre line).
    source : {"LEFT", "RIGHT"}
        The side that was sculpted (LEFT is +axis).

    Returns
    -------
    Result
        ``value`` (p, 3); unmapped vertices keep their delta (WARNING, ``diagnostics["unmapped"]``).
    """
    d = validate.array(delta, "delta", shape=(None, 3))
    co = validate.array(positions, "positions", shape=d.shape)
    source = validate.choice(source, "source", ("LEFT", "RIGHT"))
    mirror = _check_map(d, mmap)
    idx = np.arange(len(d))
    ok = mirror >= 0
    s = co[:, mmap.axis] - mmap.offset
    partner_s = np.where(ok, s[np.maximum(mirror, 0)], 0.0)
    centre = ok & (mirror == idx)
    # a vertex is a receiver when its partner is further on the source side than itself
    receiver = ok & ~centre & ((partner_s > s) if source == "LEFT" else (partner_s < s))
    out = d.copy()
    flipped = mirror_delta(d, mmap).value
    out[receiver] = flipped[receiver]
    out[centre] = 0.5 * (d[centre] + flipped[centre])
    unmapped = np.flatnonzero(~ok)
    if unmapped.size:
        return Result(out, status=Status.WARNING, diagnostics={"unmapped": unmapped.tolist()},
                      message=f"{unmapped.size} vertices have no mirror and keep their delta")
    return Result(out, diagnostics={"unmapped": []})


def topology_fingerprint(n_vertices: int, edges: ArrayLike, n_faces: int) -> dict:
    """What a stored mirror map was built for: vertex/edge/face counts and a hash of the edge list.

    Parameters
    ----------
    n_vertices : int
    edges : array_like of int, shape (e, 2)
    n_faces : int

    Returns
    -------
    dict
        ``{"vertices": int, "edges": int, "faces": int, "edge_hash": str}`` (sha1 of the int32 edge list).
    """
    e = np.ascontiguousarray(np.asarray(edges, dtype=np.int32).reshape(-1, 2))
    return {"vertices": int(n_vertices), "edges": int(len(e)), "faces": int(n_faces),
            "edge_hash": hashlib.sha1(e.tobytes()).hexdigest()}


#: Side spellings, each with its counterpart (the most specific first).
_SIDE_PAIRS = (("Left", "Right"), ("left", "right"), ("_L", "_R"), (".L", ".R"), ("-L", "-R"), ("_l", "_r"),
               (".l", ".r"))


def counterpart_name(name: str) -> str | None:
    """The shape-key name of the other side, in the same convention, or None for a name without a side.

    ``browDown_L`` ↔ ``browDown_R``, ``eyeBlinkLeft`` ↔ ``eyeBlinkRight``, ``EyeBlinkLeft`` ↔ ``EyeBlinkRight``,
    ``brow.L`` ↔ ``brow.R``, ``L_brow`` ↔ ``R_brow``, ``jawLeft`` ↔ ``jawRight`` (a motion to the left mirrors
    to one to the right); a ``.001`` tail is kept.  The side must end the name (or start it as ``L_``/``R_``),
    as in :mod:`core.names`.

    Parameters
    ----------
    name : str

    Returns
    -------
    str or None
    """
    if not isinstance(name, str):
        raise ShapeSpaceError(f"name must be a str, got {type(name).__name__}", ErrorCode.TYPE)
    stem, tail = name, ""
    if len(name) > 4 and name[-4] == "." and name[-3:].isdigit():
        stem, tail = name[:-4], name[-4:]
    for a, b in _SIDE_PAIRS:
        for x, y in ((a, b), (b, a)):
            if stem.endswith(x) and len(stem) > len(x):
                return stem[: -len(x)] + y + tail
    for x, y in (("L_", "R_"), ("R_", "L_"), ("l_", "r_"), ("r_", "l_")):
        if stem.startswith(x) and len(stem) > len(x):
            return y + stem[len(x):] + tail
    return None


def side_names(name: str) -> tuple:
    """Names of the left and right halves of a split shape: ``jawOpen`` → (``jawOpen_L``, ``jawOpen_R``).

    Parameters
    ----------
    name : str

    Returns
    -------
    tuple of two str
    """
    return f"{name}_L", f"{name}_R"


def whole_name(left: str) -> str | None:
    """The name of the combined shape of a left half: ``jawOpen_L`` → ``jawOpen``, ``eyeBlinkLeft`` →
    ``eyeBlink``; None when the name has no left side.

    Parameters
    ----------
    left : str

    Returns
    -------
    str or None
    """
    for a, b in _SIDE_PAIRS:
        for x in (a, b):
            if left.endswith(x) and len(left) > len(x):
                return left[: -len(x)].rstrip("_.-") or None
    for x in ("L_", "R_", "l_", "r_"):
        if left.startswith(x) and len(left) > len(x):
            return left[len(x):]
    return None
