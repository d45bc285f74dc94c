"""Named facial landmarks (issue #22 §3): one fixed set of 26 points users can place right, their mirror
partners, the contours between them, and the landmark file of the CLI.

Names (``_L``/``_R`` = the character's own left/right, as ARKit's ``…Left``/``…Right``):

========================  ==================================================================================
``eye_inner_L/R``         inner eye corner (where the lids meet, nose side)
``eye_outer_L/R``         outer eye corner
``lid_upper_L/R``         upper-lid margin, midway (the point eyeBlink moves most)
``lid_lower_L/R``         lower-lid margin, opposite ``lid_upper`` (where the closed upper lid lands)
``brow_inner/mid/outer``  brow, inner end / middle / outer end (L/R)
``mouth_corner_L/R``      where the upper and lower lip meet
``lip_upper_outer``       upper lip, midline, most forward point (vermilion border)
``lip_lower_outer``       lower lip, midline, most forward point
``lip_upper_inner``       upper lip, midline, on the mouth opening
``lip_lower_inner``       lower lip, midline, on the mouth opening
``nose_tip``              most forward point of the nose, midline
``nostril_L/R``           the nose wing (the point noseSneer moves most)
``chin``                  most forward point of the chin, midline
``jaw_angle_L/R``         the jaw's back lower corner (gonion) on the skin
========================  ==================================================================================

Contours (:data:`CONTOURS`): a named curve from a first to a last landmark through a middle one — the
shortest path along mesh edges from first to middle, then from middle to last (:func:`contour_paths`).

The landmark file (``transfer --landmarks FILE.json``)::

    {"version": 1,
     "source": {"eye_inner_L": 123, "eye_inner_R": 456, ...},
     "target": {"eye_inner_L": 789, ...}}

``source`` and ``target`` map landmark names (:data:`NAMES`) to vertex indices of the source rig's and the
target's mesh.  Names given on only one side are ignored (reported); at least
:data:`~core.authoring.landmarks.MIN_LANDMARKS` names must be on both.  A per-head file (one side only) is
``{"version": 1, "vertices": 2694, "landmarks": {name: index, ...}}`` (``tools/landmarks/<head>.json``).
Every error is one line naming the entry.
"""
from __future__ import annotations

import json
from collections.abc import Mapping

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike
from scipy.sparse.csgraph import dijkstra

from ..errors import ErrorCode
from ..result import ShapeSpaceError
from .landmarks import MIN_LANDMARKS

__all__ = ["NAMES", "PAIRED", "CENTRE", "CONTOURS", "FILE_VERSION", "mirror_name", "edge_graph", "shortest_path",
           "contour_paths", "check_named", "parse_landmark_file", "parse_head_file", "head_file_text",
           "load_head_file", "load_landmark_file", "shared_names"]

FILE_VERSION = 1

_SIDED = ("eye_inner", "eye_outer", "lid_upper", "lid_lower", "brow_inner", "brow_mid", "brow_outer",
          "mouth_corner", "nostril", "jaw_angle")
#: Landmarks on the midline (their own mirror image).
CENTRE = ("lip_upper_outer", "lip_lower_outer", "lip_upper_inner", "lip_lower_inner", "nose_tip", "chin")
#: Landmarks with a left and a right one, as ``(left, right)``.
PAIRED = tuple((f"{b}_L", f"{b}_R") for b in _SIDED)
#: Every landmark name, in placement order (guided placement asks for them in this order).
NAMES = (
    "eye_inner_L", "eye_outer_L", "lid_upper_L", "lid_lower_L", "eye_inner_R", "eye_outer_R", "lid_upper_R",
    "lid_lower_R", "brow_inner_L", "brow_mid_L", "brow_outer_L", "brow_inner_R", "brow_mid_R", "brow_outer_R",
    "nose_tip", "nostril_L", "nostril_R", "mouth_corner_L", "mouth_corner_R", "lip_upper_outer",
    "lip_lower_outer", "lip_upper_inner", "lip_lower_inner", "chin", "jaw_angle_L", "jaw_angle_R",
)
#: Contours: ``name -> (first, middle, last)`` landmark names.
CONTOURS = {
    "lid_upper_L": ("eye_inner_L", "lid_upper_L", "eye_outer_L"),
    "lid_lower_L": ("eye_inner_L", "lid_lower_L", "eye_outer_L"),
    "lid_upper_R": ("eye_inner_R", "lid_upper_R", "eye_outer_R"),
    "lid_lower_R": ("eye_inner_R", "lid_lower_R", "eye_outer_R"),
    "lip_upper_inner": ("mouth_corner_R", "lip_upper_inner", "mouth_corner_L"),
    "lip_lower_inner": ("mouth_corner_R", "lip_lower_inner", "mouth_corner_L"),
    "lip_upper_outer": ("mouth_corner_R", "lip_upper_outer", "mouth_corner_L"),
    "lip_lower_outer": ("mouth_corner_R", "lip_lower_outer", "mouth_corner_L"),
    "brow_L": ("brow_inner_L", "brow_mid_L", "brow_outer_L"),
    "brow_R": ("brow_inner_R", "brow_mid_R", "brow_outer_R"),
    "jaw": ("jaw_angle_R", "chin", "jaw_angle_L"),
}

_MIRROR = {**{a: b for a, b in PAIRED}, **{b: a for a, b in PAIRED}, **{c: c for c in CENTRE}}


def mirror_name(name: str) -> str:
    """The mirror partner of a landmark name (a midline landmark is its own)."""
    try:
        return _MIRROR[name]
    except KeyError:
        raise ShapeSpaceError(f"{name!r} is not a landmark name (e.g. {NAMES[0]!r})", ErrorCode.MISSING_KEY) from None


def edge_graph(verts: ArrayLike, tris: ArrayLike) -> sp.csr_matrix:
    """Symmetric sparse graph (n, n) of the mesh's edges weighted by their length."""
    V = np.asarray(verts, dtype=np.float64)
    T = np.asarray(tris, dtype=np.int64)
    e = np.concatenate([T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]])
    e = np.unique(np.sort(e, axis=1), axis=0)
    w = np.maximum(np.linalg.norm(V[e[:, 0]] - V[e[:, 1]], axis=1), 1e-12)
    n = V.shape[0]
    G = sp.coo_matrix((np.concatenate([w, w]), (np.concatenate([e[:, 0], e[:, 1]]),
                                                np.concatenate([e[:, 1], e[:, 0]]))), shape=(n, n))
    return G.tocsr()


def shortest_path(graph: sp.csr_matrix, a: int, b: int) -> np.ndarray:
    """Vertex indices of the shortest edge path from ``a`` to ``b`` (both included); empty if unconnected."""
    dist, pred = dijkstra(graph, indices=int(a), return_predecessors=True)
    if not np.isfinite(dist[int(b)]):
        return np.zeros(0, dtype=np.int64)
    path = [int(b)]
    while path[-1] != int(a):
        path.append(int(pred[path[-1]]))
    return np.array(path[::-1], dtype=np.int64)


def contour_paths(verts: ArrayLike, tris: ArrayLike, landmarks: Mapping[str, int],
                  names: tuple | None = None, corridor: float = 0.3) -> dict:
    """The vertex path of each contour whose three landmarks are given.

    Parameters
    ----------
    verts : array_like (n, 3)
    tris : array_like of int (f, 3)
    landmarks : mapping of str to int
        Named landmark vertices of this mesh (e.g. one side of a landmark file).
    names : tuple of str, optional
        Contours wanted (default: every one of :data:`CONTOURS` whose landmarks are all given).
    corridor : float
        Each half (first → middle, middle → last) keeps to the vertices within this × its length of the
        straight segment between its landmarks when such a path exists, else within three times that, else
        anywhere on the mesh (0: anywhere).

    Returns
    -------
    dict of str to ndarray of int
        ``contour -> (p,)`` vertex indices from its first landmark through its middle one to its last
        (shortest paths along mesh edges, within the corridor).  A contour whose landmarks are not connected
        by edges is left out.
    """
    wanted = tuple(CONTOURS) if names is None else tuple(names)
    for c in wanted:
        if c not in CONTOURS:
            raise ShapeSpaceError(f"no contour named {c!r} (one of {', '.join(CONTOURS)})", ErrorCode.MISSING_KEY)
    G = edge_graph(verts, tris)
    V = np.asarray(verts, dtype=np.float64)
    out = {}
    for c in wanted:
        ends = CONTOURS[c]
        if not all(k in landmarks for k in ends):
            continue
        a, m, b = (int(landmarks[k]) for k in ends)
        first, second = _corridor_path(G, V, a, m, corridor), _corridor_path(G, V, m, b, corridor)
        if first.size and second.size:
            out[c] = np.concatenate([first, second[1:]])
    return out


def _corridor_path(G: sp.csr_matrix, V: np.ndarray, a: int, b: int, corridor: float) -> np.ndarray:
    """Shortest edge path from ``a`` to ``b`` through the vertices within ``corridor`` × |ab| of the segment ab
    (so that it follows the feature, not a detour through a mouth bag); unrestricted when that has none."""
    p, q = V[a], V[b]
    d = q - p
    t = np.clip((V - p) @ d / max(float(d @ d), 1e-300), 0.0, 1.0)
    off = np.linalg.norm(V - (p + t[:, None] * d), axis=1) / max(float(np.linalg.norm(d)), 1e-300)
    for width in (corridor, 3.0 * corridor) if corridor > 0 else ():       # a wider corridor before none
        near = np.flatnonzero(off <= width)
        local = {int(v): k for k, v in enumerate(near)}
        if a in local and b in local:
            path = shortest_path(G[near][:, near], local[a], local[b])
            if path.size:
                return near[path]
    return shortest_path(G, a, b)


def _index(value, where: str, n_verts: int | None) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ShapeSpaceError(f"{where}: the vertex index must be a whole number, not {value!r}", ErrorCode.TYPE)
    if value < 0 or (n_verts is not None and value >= n_verts):
        size = f" (the mesh has {n_verts} vertices)" if n_verts is not None else ""
        raise ShapeSpaceError(f"{where}: vertex {value} does not exist{size}", ErrorCode.RANGE)
    return value


def check_named(entries: Mapping | object, where: str, n_verts: int | None = None) -> dict:
    """Validate one ``{name: vertex index}`` object; returns it as a dict in :data:`NAMES` order.

    Raises
    ------
    ShapeSpaceError
        One line naming the entry: not an object, unknown name, a non-integer or out-of-range index, two
        names on one vertex.
    """
    if not isinstance(entries, Mapping):
        raise ShapeSpaceError(f"{where}: must be an object of landmark name -> vertex index", ErrorCode.TYPE)
    seen = {}
    for name, value in entries.items():
        if name not in _MIRROR:
            raise ShapeSpaceError(f"{where}.{name}: not a landmark name (known: {', '.join(NAMES)})",
                                  ErrorCode.MISSING_KEY)
        v = _index(value, f"{where}.{name}", n_verts)
        if v in seen:
            raise ShapeSpaceError(f"{where}.{name}: vertex {v} is already {seen[v]!r}", ErrorCode.DEGENERATE)
        seen[v] = name
    return {n: int(entries[n]) for n in NAMES if n in entries}


def _json(text: str, where: str) -> dict:
    try:
        data = json.loads(text)
    except (ValueError, TypeError) as exc:
        raise ShapeSpaceError(f"{where}: not valid JSON ({exc})", ErrorCode.CORRUPT_FILE) from None
    if not isinstance(data, dict):
        raise ShapeSpaceError(f"{where}: must be a JSON object with \"version\"", ErrorCode.CORRUPT_FILE)
    version = data.get("version")
    if version != FILE_VERSION:
        raise ShapeSpaceError(f"{where}.version: {version!r} is not a supported landmark file version "
                              f"({FILE_VERSION})", ErrorCode.UNSUPPORTED_FILE)
    return data


def parse_landmark_file(text: str, where: str = "landmark file", source_vertices: int | None = None,
                        target_vertices: int | None = None) -> tuple:
    """Parse and validate a landmark file of named source and target vertices (format: module docstring).

    Returns
    -------
    source, target : dict of str to int
        Both restricted to the names given on both sides, in :data:`NAMES` order.
    ignored : list of str
        Names given on one side only.

    Raises
    ------
    ShapeSpaceError
        One line naming the entry (``<where>.source.eye_inner_L: …``); fewer than
        :data:`~core.authoring.landmarks.MIN_LANDMARKS` names on both sides.
    """
    data = _json(text, where)
    for key in ("source", "target"):
        if key not in data:
            raise ShapeSpaceError(f"{where}: no \"{key}\" object of landmark name -> vertex index",
                                  ErrorCode.MISSING_KEY)
    src = check_named(data["source"], f"{where}.source", source_vertices)
    dst = check_named(data["target"], f"{where}.target", target_vertices)
    both = [n for n in NAMES if n in src and n in dst]
    ignored = [n for n in NAMES if (n in src) != (n in dst)]
    if len(both) < MIN_LANDMARKS:
        raise ShapeSpaceError(f"{where}: {len(both)} landmark names are on both source and target; at least "
                              f"{MIN_LANDMARKS} are needed", ErrorCode.TOO_FEW_LANDMARKS)
    return {n: src[n] for n in both}, {n: dst[n] for n in both}, ignored


def parse_head_file(text: str, where: str = "head landmark file", n_verts: int | None = None) -> dict:
    """Parse a per-head file ``{"version": 1, "vertices": n, "landmarks": {name: index}}``; refuses one placed
    on a mesh of another vertex count than ``n_verts``."""
    data = _json(text, where)
    count = data.get("vertices")
    if isinstance(count, bool) or not isinstance(count, int) or count <= 0:
        raise ShapeSpaceError(f"{where}.vertices: the mesh's vertex count is needed, not {count!r}", ErrorCode.TYPE)
    if n_verts is not None and count != n_verts:
        raise ShapeSpaceError(f"{where}: placed on a mesh of {count} vertices, this one has {n_verts}",
                              ErrorCode.VERTEX_COUNT_MISMATCH)
    return check_named(data.get("landmarks"), f"{where}.landmarks", count)


def head_file_text(landmarks: Mapping[str, int], n_verts: int, notes: Mapping | None = None) -> str:
    """The JSON text of a per-head file (``notes``: optional per-name strings saying how each was chosen)."""
    data = {"version": FILE_VERSION, "vertices": int(n_verts),
            "landmarks": check_named(dict(landmarks), "landmarks", n_verts)}
    if notes:
        data["notes"] = {str(k): str(v) for k, v in notes.items()}
    return json.dumps(data, indent=1) + "\n"


def load_head_file(path: str, n_verts: int | None = None) -> dict:
    """:func:`parse_head_file` of a file on disk."""
    with open(path, encoding="utf-8") as fh:
        return parse_head_file(fh.read(), path, n_verts)


def load_landmark_file(path: str, source_vertices: int | None = None, target_vertices: int | None = None) -> tuple:
    """:func:`parse_landmark_file` of a file on disk."""
    try:
        with open(path, encoding="utf-8") as fh:
            text = fh.read()
    except FileNotFoundError:
        raise ShapeSpaceError(f"landmark file not found: {path}", ErrorCode.MISSING_FILE) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ShapeSpaceError(f"{path}: cannot be read ({exc})", ErrorCode.CORRUPT_FILE) from None
    return parse_landmark_file(text, path, source_vertices, target_vertices)


def shared_names(a: Mapping, b: Mapping) -> list:
    """Names present in both mappings, in :data:`NAMES` order."""
    return [n for n in NAMES if n in a and n in b]
