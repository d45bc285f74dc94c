"""Facial features for the named landmarks (:mod:`.named`): the face frame, the eye and mouth openings, and
the named points of a rig located from its own shapes.

- :func:`face_frame_from_shapes` — left / up / forward axes of a rig: left = the mirror-plane normal towards
  the vertices ``eyeBlinkLeft`` moves, up = from the mouth (``mouthPucker``) to the eyes, forward = left × up;
- :func:`opening_ring` — the vertices around an opening (an eye, the mouth): the skin's hole loop there when
  the mesh is open, else the rim of the socket behind it (the skin facing away from the front, grown from the
  deepest point near the opening; its outer neighbours are the rim);
- :func:`locate_from_shapes` — every named landmark of a rig from its ARKit shapes and the openings (how
  each one is found: :data:`HOW`);
- :func:`locate_on_geometry` — the same geometric rules given a face frame and rough positions (a head
  without shapes: the automatic proposal's refinement).

Everything works on the *skin*: the largest connected part of the mesh (eyes, teeth, lashes are other parts).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from ..errors import ErrorCode
from ..names import canonical_name
from ..result import ShapeSpaceError
from .mesh import bbox_diagonal, symmetry_plane, triangle_parts, vertex_normals
from .named import NAMES, edge_graph, shortest_path

__all__ = ["FaceFrame", "HOW", "boundary_loops", "face_frame_from_shapes", "opening_ring", "locate_from_shapes",
           "locate_on_geometry", "Head"]

#: How :func:`locate_from_shapes` finds each landmark (by name without side).
HOW = {
    "lid_upper": "the vertex of the eye opening's rim that eyeBlink moves most",
    "lid_lower": "the vertex of the eye opening's rim below the corners' line opposite lid_upper (nearest across)",
    "eye_inner": "the rim vertex of the eye opening nearest the midplane (its medial extreme)",
    "eye_outer": "the rim vertex of the eye opening farthest from the midplane (its lateral extreme)",
    "brow_inner": "the vertex on that side browInnerUp moves most",
    "brow_outer": "the vertex browOuterUp moves most",
    "brow_mid": "the middle (by length) of the shortest edge path from brow_inner to brow_outer",
    "mouth_corner": "the lateral extreme of the mouth opening's rim",
    "lip_upper_inner": "the rim vertex of the mouth opening nearest the midline, upper lip",
    "lip_lower_inner": "the rim vertex of the mouth opening nearest the midline, lower lip",
    "lip_upper_outer": "the most forward midline vertex of the upper lip (below the nose tip's half-way)",
    "lip_lower_outer": "the most forward midline vertex of the lower lip (0.25 eye distances below the opening)",
    "nose_tip": "the most forward midline vertex between the mouth and the eyes (profile points: in the frame of "
                "the head's mirror plane and the line from its mouth landmarks to its eye landmarks)",
    "nostril": "the vertex on that side noseSneer moves most within 0.35 eye distances of the midline",
    "chin": "the chin's corner: the midline vertex farthest forward-and-down (45°) 0.15 to 1 eye distances below "
            "the lower lip",
    "jaw_angle": "the most backward outward-facing vertex on that side, 0.6 eye distances or more from the "
                 "midline, that jawOpen moves by at least 30 % of its peak, at or below the mouth",
}


@dataclass
class FaceFrame:
    """A head's face frame: ``origin`` (3,) on the mirror plane, ``axes`` (3, 3) rows left, up, forward."""

    origin: np.ndarray
    axes: np.ndarray

    def coords(self, points: np.ndarray) -> np.ndarray:
        """(m, 3) points → (m, 3) (left, up, forward) coordinates relative to the origin."""
        return (np.asarray(points, dtype=np.float64) - self.origin) @ self.axes.T


@dataclass
class Head:
    """A mesh prepared for feature finding: vertices, triangles, skin mask, normals, edge graph, diagonal."""

    verts: np.ndarray
    tris: np.ndarray
    skin: np.ndarray
    normals: np.ndarray
    graph: sp.csr_matrix
    diag: float

    @classmethod
    def of(cls, verts: ArrayLike, tris: ArrayLike) -> Head:
        V = np.asarray(verts, dtype=np.float64)
        T = np.asarray(tris, dtype=np.int64)
        part, _ = triangle_parts(V.shape[0], T)
        skin = part == 0
        skin_tris = T[skin[T[:, 0]]]
        return cls(V, skin_tris, skin, vertex_normals(V, skin_tris), edge_graph(V, skin_tris),
                   bbox_diagonal(V[skin]))


def boundary_loops(n: int, tris: np.ndarray) -> list:
    """Vertex index arrays of the mesh's boundary loops (connected sets of boundary edges; unordered)."""
    e = np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1)
    u, c = np.unique(e, axis=0, return_counts=True)
    b = u[c == 1]
    if not b.size:
        return []
    A = sp.coo_matrix((np.ones(len(b)), (b[:, 0], b[:, 1])), shape=(n, n))
    _, lab = connected_components(A, directed=False)
    used = np.zeros(n, dtype=bool)
    used[b.ravel()] = True
    return [np.flatnonzero((lab == k) & used) for k in np.unique(lab[used])]


def _shape(names, deltas, skin, *wanted):
    """Per-vertex motion (n,) of the first wanted shape the rig has (summed over a Left/Right pair given as a
    tuple), zero off the skin; None when the rig has none of them."""
    canon = [canonical_name(n) for n in names]
    for w in wanted:
        parts = w if isinstance(w, tuple) else (w,)
        if all(p in canon for p in parts):
            m = sum(np.linalg.norm(deltas[canon.index(p)], axis=1) for p in parts)
            if np.any(m[skin] > 0):
                return np.where(skin, m, 0.0)
    return None


def _need(motion, what):
    if motion is None:
        raise ShapeSpaceError(f"the rig has no {what} shape moving its skin: its named landmarks cannot be found "
                              f"from its shapes", ErrorCode.MISSING_KEY)
    return motion


def face_frame_from_shapes(head: Head, deltas: np.ndarray, names: Sequence[str]) -> FaceFrame:
    """The face frame of a rig from its mirror plane and its eyeBlinkLeft and mouthPucker shapes."""
    V, skin = head.verts, head.skin
    normal, offset, _ = symmetry_plane(V[skin])
    blink_l = _need(_shape(names, deltas, skin, "eyeBlinkLeft", "eyeSquintLeft"), "eyeBlinkLeft")
    blink = _need(_shape(names, deltas, skin, ("eyeBlinkLeft", "eyeBlinkRight"), "eyeBlinkLeft"), "eyeBlink")
    mouth = _need(_shape(names, deltas, skin, "mouthPucker", "mouthFunnel", "jawOpen"), "mouthPucker")

    def centre(m):
        return V[m >= 0.5 * m.max()].mean(axis=0)

    left = normal if (centre(blink_l) @ normal - offset) > 0 else -normal
    up = centre(blink) - centre(mouth)
    up = up - (up @ left) * left
    up /= np.linalg.norm(up)
    fwd = np.cross(left, up)
    c = centre(mouth)
    return FaceFrame(c - (c @ left - offset * (1 if left @ normal > 0 else -1)) * left, np.stack([left, up, fwd]))


def opening_ring(head: Head, frame: FaceFrame, near: np.ndarray, radius: float, facing: float = 0.3) -> np.ndarray:
    """Vertex indices around an opening (an eye, the mouth) near the point ``near`` (3,).

    The skin's boundary loop with a vertex within ``radius`` of ``near`` when there is one (an open mesh);
    else the rim of the socket: the skin vertices within ``radius`` whose normal faces away from the front
    (normal · forward < ``facing``), grown from the deepest of them, and their neighbours outside that region
    that are not hidden behind another of them (1 % of the diagonal or more behind one within 1 % in the
    frontal plane: the socket's back wall).  Empty when neither is found (``facing`` ≤ −1: hole loops only).
    """
    V = head.verts
    loops = boundary_loops(V.shape[0], head.tris)
    best = None
    for loop in loops:
        d = np.linalg.norm(V[loop] - near, axis=1).min()
        if d <= radius and (best is None or d < best[0]) and np.ptp(V[loop], axis=0).max() < 2.5 * radius:
            best = (d, loop)
    if best is not None:
        return best[1]
    cand = head.skin & (np.linalg.norm(V - near, axis=1) <= radius) & (head.normals @ frame.axes[2] < facing)
    idx = np.flatnonzero(cand)
    if not idx.size:
        return idx
    seed = idx[np.argmin(frame.coords(V[idx])[:, 2])]
    sub = head.graph[idx][:, idx]
    _, lab = connected_components(sub, directed=False)
    region = idx[lab == lab[np.searchsorted(idx, seed)]]
    inside = np.zeros(V.shape[0], dtype=bool)
    inside[region] = True
    nb = head.graph[region].tocoo().col
    rim = np.unique(nb[~inside[nb] & head.skin[nb]])
    X = frame.coords(V[rim])
    flat = np.linalg.norm(X[:, None, :2] - X[None, :, :2], axis=2) <= 0.01 * head.diag
    hidden = (flat & (X[None, :, 2] - X[:, None, 2] >= 0.01 * head.diag)).any(axis=1)
    return rim[~hidden]


def contact_band(head: Head, frame: FaceFrame, near: np.ndarray, radius: float, gap: float = 0.012,
                 apart: float = 0.06, slab: float = 0.03) -> tuple:
    """Where a closed opening's two sides touch (the lips of a mouth modelled closed, with a mouth bag
    behind): skin vertices within ``radius`` of ``near`` that have another vertex closer than ``gap`` × the
    head's diagonal which is more than ``apart`` × the diagonal away along the mesh's edges.

    Returns
    -------
    band : ndarray of int (m,)
    partner : ndarray of int (m,)
        The touching vertex of each.
    """
    V = head.verts
    height = frame.coords(V)[:, 1] - frame.coords(near[None])[0, 1]
    idx = np.flatnonzero(head.skin & (np.linalg.norm(V - near, axis=1) <= radius)
                         & (np.abs(height) <= slab * head.diag))
    if idx.size < 4:
        return idx[:0], idx[:0]
    geo = dijkstra(head.graph[idx][:, idx], directed=False, limit=apart * head.diag)
    tree = cKDTree(V[idx])
    pairs = tree.query_pairs(gap * head.diag, output_type="ndarray")
    far = ~np.isfinite(geo[pairs[:, 0], pairs[:, 1]])
    pairs = pairs[far]
    if not pairs.size:
        return idx[:0], idx[:0]
    d = np.linalg.norm(V[idx[pairs[:, 0]]] - V[idx[pairs[:, 1]]], axis=1)
    both = np.concatenate([pairs, pairs[:, ::-1]])
    dd = np.concatenate([d, d])
    order = np.lexsort((dd, both[:, 0]))
    both = both[order]
    first = np.unique(both[:, 0], return_index=True)[1]
    return idx[both[first, 0]], idx[both[first, 1]]


def _midline(head: Head, frame: FaceFrame, tol: float = 0.004) -> np.ndarray:
    X = frame.coords(head.verts)
    return np.flatnonzero(head.skin & (np.abs(X[:, 0]) <= tol * head.diag))


def _argmax(idx, score):
    return int(idx[int(np.argmax(score))]) if len(idx) else -1


def _lid_split(X: np.ndarray) -> tuple:
    """Of an eye opening's rim in face coordinates (m, 3): the inner and outer corner (medial and lateral
    extremes) and which rim vertices are on the upper lid (on or above the line through the corners)."""
    lat = np.abs(X[:, 0])
    inner, outer = int(np.argmin(lat)), int(np.argmax(lat))
    t = (X[:, 0] - X[inner, 0]) / (X[outer, 0] - X[inner, 0] or 1.0)
    return inner, outer, X[:, 1] >= X[inner, 1] + t * (X[outer, 1] - X[inner, 1])


def _eye(head: Head, frame: FaceFrame, blink: np.ndarray, blink_delta: np.ndarray, side: str) -> dict:
    """lid_upper / lid_lower / eye_inner / eye_outer of one eye from its blink motion (n,) and deltas (n, 3)."""
    V = head.verts
    top = int(np.argmax(blink))
    landed = V[top] + blink_delta[top]
    ring = opening_ring(head, frame, 0.5 * (V[top] + landed), 0.08 * head.diag)
    if ring.size < 4:
        raise ShapeSpaceError(f"no eye opening found around vertex {top} (eye {side})", ErrorCode.DEGENERATE)
    X = frame.coords(V[ring])
    inner, outer, above = _lid_split(X)
    upper = _argmax(ring[above], blink[ring[above]]) if above.any() else -1
    lower = -1
    if upper >= 0 and (~above).any():                # opposite the upper lid (across the opening)
        lower = int(ring[~above][np.argmin(np.abs(X[~above, 0] - frame.coords(V[[upper]])[0, 0]))])
    return {f"lid_upper_{side}": upper, f"lid_lower_{side}": lower,
            f"eye_inner_{side}": int(ring[inner]), f"eye_outer_{side}": int(ring[outer])}


def _nearest_midline(idx: np.ndarray, X: np.ndarray, diag: float) -> int:
    """The vertex nearest the midline; of several as near (within 0.01 % of the diagonal) the one on the left
    (a loop with an edge, not a vertex, on the midline), then the most forward."""
    near = np.abs(X[:, 0]) <= np.abs(X[:, 0]).min() + 1e-4 * diag
    side = np.round(X[near, 0] / (1e-4 * diag))
    return int(idx[near][np.lexsort((X[near, 2], side))[-1]])


def _mouth(head: Head, frame: FaceFrame, near: np.ndarray, radius: float = 0.12) -> dict:
    """Mouth corners and inner lip midpoints from the mouth opening's rim around ``near`` (a hole loop), else
    from where the lips touch (:func:`contact_band`)."""
    ring = opening_ring(head, frame, near, radius * head.diag, facing=-2.0)
    if ring.size < 4:
        band, partner = contact_band(head, frame, near, radius * head.diag)
        if band.size < 4:
            raise ShapeSpaceError("no mouth opening found", ErrorCode.DEGENERATE)
        return _mouth_band(head, frame, band, partner)
    X = frame.coords(head.verts[ring])
    left, right = int(np.argmax(X[:, 0])), int(np.argmin(X[:, 0]))
    # the loop without its corners falls into the upper and the lower lip (the lips may touch: not by height)
    keep = np.ones(ring.size, dtype=bool)
    keep[[left, right]] = False
    n_arcs, arc = connected_components(head.graph[ring[keep]][:, ring[keep]], directed=False)
    if n_arcs == 2:
        up_arc = int(np.argmax([X[keep][arc == a, 1].mean() for a in range(2)]))
        hi, lo = np.flatnonzero(keep)[arc == up_arc], np.flatnonzero(keep)[arc != up_arc]
    else:
        centre_up = np.median(X[:, 1])
        hi, lo = np.flatnonzero(X[:, 1] >= centre_up), np.flatnonzero(X[:, 1] <= centre_up)
    upper, lower = _nearest_midline(ring[hi], X[hi], head.diag), _nearest_midline(ring[lo], X[lo], head.diag)
    return {"mouth_corner_L": int(ring[left]), "mouth_corner_R": int(ring[right]),
            "lip_upper_inner": upper, "lip_lower_inner": lower}


def _mouth_band(head: Head, frame: FaceFrame, band: np.ndarray, partner: np.ndarray) -> dict:
    """Mouth corners (the band's lateral extremes) and inner lip midpoints (the band's most forward midline
    vertex whose partner is below it: upper lip; above it: lower lip) from where the lips touch."""
    X, P = frame.coords(head.verts[band]), frame.coords(head.verts[partner])
    width = np.ptp(X[:, 0])
    mid = np.abs(X[:, 0]) <= 0.1 * width
    out = {"mouth_corner_L": int(band[np.argmax(X[:, 0])]), "mouth_corner_R": int(band[np.argmin(X[:, 0])])}
    for name, sel in (("lip_upper_inner", mid & (P[:, 1] < X[:, 1])), ("lip_lower_inner", mid & (P[:, 1] > X[:, 1]))):
        if sel.any():
            out[name] = int(band[sel][np.argmax(X[sel, 2])])
    return out


def _profile(head: Head, frame: FaceFrame, out: dict) -> dict:
    """Nose tip, outer lip midpoints and chin on the midline profile, given the mouth and eye landmarks."""
    line = _midline(head, frame)
    X = frame.coords(head.verts[line])
    C = frame.coords(head.verts)
    ui, li = C[out["lip_upper_inner"], 1], C[out["lip_lower_inner"], 1]
    eye = 0.5 * (C[out["lid_upper_L"], 1] + C[out["lid_upper_R"], 1])
    eyes = abs(C[out["lid_upper_L"], 0] - C[out["lid_upper_R"], 0])          # the scale: eye to eye
    res = {}
    win = (X[:, 1] > ui) & (X[:, 1] < eye)
    res["nose_tip"] = _argmax(line[win], X[win, 2])
    nose = C[res["nose_tip"], 1] if res["nose_tip"] >= 0 else eye
    win = (X[:, 1] >= ui) & (X[:, 1] < ui + 0.35 * (nose - ui))
    res["lip_upper_outer"] = _argmax(line[win], X[win, 2])
    win = (X[:, 1] <= li) & (X[:, 1] > li - 0.25 * eyes)
    res["lip_lower_outer"] = _argmax(line[win], X[win, 2])
    lo = C[res["lip_lower_outer"], 1] if res["lip_lower_outer"] >= 0 else li
    # the chin's corner (gnathion): the profile's extreme forward-and-down, for prominent and receding chins
    win = (X[:, 1] < lo - 0.15 * eyes) & (X[:, 1] > lo - 1.0 * eyes)
    res["chin"] = _argmax(line[win], X[win, 2] - X[win, 1])
    return res


def _side(head: Head, frame: FaceFrame, side: str) -> np.ndarray:
    x = frame.coords(head.verts)[:, 0]
    return head.skin & ((x > 0.01 * head.diag) if side == "L" else (x < -0.01 * head.diag))


def _brow(head: Head, frame: FaceFrame, inner: np.ndarray, outer: np.ndarray, side: str) -> dict:
    mask = _side(head, frame, side)
    a = _argmax(np.flatnonzero(mask), inner[mask])
    b = _argmax(np.flatnonzero(mask), outer[mask])
    path = shortest_path(head.graph, a, b)
    if path.size:
        seg = np.linalg.norm(np.diff(head.verts[path], axis=0), axis=1)
        along = np.concatenate([[0.0], np.cumsum(seg)])
        m = int(path[np.argmin(np.abs(along - 0.5 * along[-1]))])
    else:
        m = -1
    return {f"brow_inner_{side}": a, f"brow_mid_{side}": m, f"brow_outer_{side}": b}


def _jaw(head: Head, frame: FaceFrame, jaw: np.ndarray, mouth_up: float, side: str, eyes: float) -> int:
    """The most backward outer-skin vertex on that side jawOpen moves by ≥ 30 % of its peak, at or below the
    mouth: at least 0.6 eye distances from the midline and facing outwards (not the inside of a mouth bag)."""
    C = frame.coords(head.verts)
    sign = 1.0 if side == "L" else -1.0
    mask = (_side(head, frame, side) & (jaw >= 0.3 * jaw.max()) & (C[:, 1] <= mouth_up)
            & (np.abs(C[:, 0]) >= 0.6 * eyes) & (sign * head.normals @ frame.axes[0] > 0))
    return _argmax(np.flatnonzero(mask), -C[mask, 2])


def _own_frame(head: Head, frame: FaceFrame, marks: dict) -> FaceFrame:
    """The head's own frame from its eye and mouth landmarks: left = its mirror normal (the sign of ``frame``'s),
    up = from the mouth (corners and inner lips) to the eyes (corners and lids), origin on the mirror plane.
    The midline profile is measured in it, so that a head's profile points do not depend on how another
    head's frame was tilted onto it."""
    V = head.verts
    normal, offset, _ = symmetry_plane(V[head.skin])
    left = normal if normal @ frame.axes[0] > 0 else -normal
    eyes = [marks[n] for n in marks if n.startswith(("lid_", "eye_"))]
    mouth = [marks[n] for n in ("mouth_corner_L", "mouth_corner_R", "lip_upper_inner", "lip_lower_inner")
             if n in marks]
    if not eyes or not mouth:
        return frame
    up = V[eyes].mean(axis=0) - V[mouth].mean(axis=0)
    up -= (up @ left) * left
    if np.linalg.norm(up) == 0:
        return frame
    up /= np.linalg.norm(up)
    origin = V[mouth].mean(axis=0)
    origin = origin - (origin @ left - offset * (normal @ left)) * left
    return FaceFrame(origin, np.stack([left, up, np.cross(left, up)]))


def locate_from_shapes(verts: ArrayLike, tris: ArrayLike, deltas: ArrayLike, names: Sequence[str]) -> tuple:
    """Every named landmark of a rig, found from its own ARKit shapes and its eye and mouth openings.

    Parameters
    ----------
    verts : array_like (n, 3)
    tris : array_like of int (f, 3)
    deltas : array_like (k, n, 3)
    names : sequence of str (k,)
        ARKit names (any convention :func:`core.names.canonical_name` knows).

    Returns
    -------
    landmarks : dict of str to int
        Name → vertex index, in :data:`~.named.NAMES` order (a landmark that cannot be found is left out).
    frame : FaceFrame
    """
    head = Head.of(verts, tris)
    D = np.asarray(deltas, dtype=np.float64)
    frame = face_frame_from_shapes(head, D, names)
    canon = [canonical_name(n) for n in names]
    out = {}
    for side, full in (("L", "Left"), ("R", "Right")):
        k = canon.index(f"eyeBlink{full}") if f"eyeBlink{full}" in canon else None
        if k is None:
            continue
        blink = np.where(head.skin, np.linalg.norm(D[k], axis=1), 0.0)
        out.update(_eye(head, frame, blink, D[k], side))
    pucker = _need(_shape(names, D, head.skin, "mouthPucker", "mouthFunnel"), "mouthPucker")
    near = frame.origin
    near = near + frame.axes[1] * (frame.coords(head.verts[pucker >= 0.5 * pucker.max()])[:, 1].mean())
    out.update(_mouth(head, frame, near))
    if all(k in out for k in ("lid_upper_L", "lid_upper_R")):
        out.update(_profile(head, _own_frame(head, frame, out), out))
    C = frame.coords(head.verts)
    eyes = abs(C[out["lid_upper_L"], 0] - C[out["lid_upper_R"], 0]) if "lid_upper_L" in out and "lid_upper_R" in out \
        else 0.0
    for side, full in (("L", "Left"), ("R", "Right")):
        inner = _shape(names, D, head.skin, f"browInnerUp{full}", "browInnerUp")
        outer = _shape(names, D, head.skin, f"browOuterUp{full}")
        if inner is not None and outer is not None:
            out.update(_brow(head, frame, inner, outer, side))
        sneer = _shape(names, D, head.skin, f"noseSneer{full}")
        if sneer is not None and eyes > 0:          # on the nose (not the cheek noseSneer may pull more)
            mask = _side(head, frame, side) & (np.abs(C[:, 0]) <= 0.35 * eyes)
            out[f"nostril_{side}"] = _argmax(np.flatnonzero(mask), sneer[mask])
    jaw = _shape(names, D, head.skin, "jawOpen")
    if jaw is not None and eyes > 0:
        mouth_up = C[out["mouth_corner_L"], 1]
        for side in ("L", "R"):
            out[f"jaw_angle_{side}"] = _jaw(head, frame, jaw, mouth_up, side, eyes)
    return {n: int(out[n]) for n in NAMES if out.get(n, -1) >= 0}, frame


def locate_on_geometry(head: Head, frame: FaceFrame, rough: dict) -> tuple:
    """Named landmarks refined on a head's geometry alone, starting from rough vertex positions.

    The eye and mouth landmarks are re-found on the openings' rims around their rough positions (upper lid =
    the rim vertex nearest the rough one, above the opening's centre; lower lid opposite it; corners the rim's
    lateral extremes), the midline ones on the midline profile (:data:`HOW`).  Landmarks without a
    geometric rule keep their rough vertex.

    Parameters
    ----------
    head : Head
    frame : FaceFrame
        The head's face frame (e.g. the source's, moved by the fitted similarity).
    rough : dict of str to int
        Rough vertex per name (e.g. the source's landmarks moved onto this head and snapped).

    Returns
    -------
    refined : dict of str to int
    supported : dict of str to bool
        Whether a geometric feature (an opening's rim, the midline profile) confirmed the landmark.
    """
    V = head.verts
    out = dict(rough)
    supported = {n: False for n in rough}
    for side in ("L", "R"):
        names = [f"lid_upper_{side}", f"lid_lower_{side}", f"eye_inner_{side}", f"eye_outer_{side}"]
        if not all(n in rough for n in names):
            continue
        centre = V[[rough[n] for n in names]].mean(axis=0)
        ring = opening_ring(head, frame, centre, 0.08 * head.diag)
        if ring.size < 4:
            continue
        X = frame.coords(V[ring])
        inner, outer, above = _lid_split(X)
        up_half, low_half = ring[above], ring[~above]
        if up_half.size and low_half.size:
            out[names[0]] = int(up_half[np.argmin(np.linalg.norm(V[up_half] - V[rough[names[0]]], axis=1))])
            across = np.abs(X[~above, 0] - frame.coords(V[[out[names[0]]]])[0, 0])   # opposite the upper lid
            out[names[1]] = int(low_half[np.argmin(across)])
            supported[names[0]] = supported[names[1]] = True
        out[names[2]], out[names[3]] = int(ring[inner]), int(ring[outer])
        supported[names[2]] = supported[names[3]] = True
    mouth = ("mouth_corner_L", "mouth_corner_R", "lip_upper_inner", "lip_lower_inner")
    if all(n in rough for n in mouth):
        centre = V[[rough[n] for n in mouth]].mean(axis=0)
        try:
            found = _mouth(head, frame, centre)
        except ShapeSpaceError:
            found = {}
        out.update(found)
        supported.update({n: True for n in found})
        normal, offset, _ = symmetry_plane(V[head.skin])
        for n in ("lip_upper_inner", "lip_lower_inner"):
            # no rim vertex on the midline (an edge crosses it): which side's vertex is a guess
            if n in found:
                supported[n] = bool(abs(V[out[n]] @ normal - offset) <= 0.004 * head.diag)
    if all(n in out for n in ("lip_upper_inner", "lip_lower_inner", "mouth_corner_L", "mouth_corner_R",
                              "lid_upper_L", "lid_upper_R")):
        prof = {k: v for k, v in _profile(head, _own_frame(head, frame, out), out).items() if v >= 0}
        out.update(prof)
        supported.update({n: True for n in prof})
    return out, supported
