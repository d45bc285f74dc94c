"""Contact across the eye and mouth openings in deformation transfer (issue #22 §2, §4; thesis 3.4.1 [205]).

Deformation transfer carries each triangle's deformation, not the distance between two lids: nothing ties the
upper lid to the lower one, so a blink transferred onto a head with bigger eyes stops half way, and a lid
that closes on a smaller eye crosses the other.  The fix of the literature is to connect the two sides of an
opening (Sumner & Popović's virtual triangles across the eyes and mouth); here the connection is explicit.
An *opening* is two facing contours (upper and lower lid, upper and lower inner lip), each a vertex path
from one corner to the other, on the source and on the target.  Facing points are paired by arc length
(:func:`facing_pairs`), and for every shape the source's *closure* of each pair,

    c = 1 − (G′ · G) / ‖G‖²,   G = u − l (neutral gap),  G′ = (u + d_u) − (l + d_l),

(0: the gap is kept, 1: closed, < 0: opened further) is carried to the target pair at the same arc-length
parameter as the constraint

    d_u − d_l = −c · (u − l)        (target neutral gap, so a blink travels the *target's* lid gap)

added to the least-squares system with weight ``w`` (:func:`constraint_matrix`).  Where the source's
contours meet at a shape's full weight the target's meet, where the source keeps them apart so does the
target, at the target's own proportions (a stylised big eye closes over its own gap, not the source's).
Lips that touch at rest have no gap to take a fraction of: such an opening (mode ``offset``) is not carried
(:func:`carried` says why) but checked: lips that meet on the source must meet on the target.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike

from ..errors import ErrorCode
from ..names import canonical_name
from ..result import ShapeSpaceError
from .named import contour_paths

__all__ = ["Opening", "SHUT", "OPENINGS", "facing_pairs", "opening", "openings_from_named", "constraint_matrix",
           "closures", "gap_changes", "carried", "gap_fractions", "gap_left", "with_references", "CLOSING",
           "REFERENCE_MIN"]


@dataclass
class Opening:
    """One opening's facing pairs on the source and the target.

    Attributes
    ----------
    name : str
        ``eye_L``, ``eye_R``, ``mouth``.
    source_pairs : ndarray of int (m_s, 2)
        (upper, lower) source vertices facing each other.
    source_t : ndarray (m_s,)
        Their arc-length parameter in [0, 1], increasing.
    target_pairs : ndarray of int (m_t, 2)
    target_t : ndarray (m_t,)
    mode : {"ratio", "offset"}
        ``ratio``: the source's closure is carried onto the target's own gap (eyes); ``offset``: the opening
        is shut on either head at rest (lips that touch): it has no gap to take a fraction of, and is only
        checked (see :func:`carried`).
    scale : float
        Target contour length over the source's (the feature's size ratio: a smile on a small mouth moves
        its corners in proportion).
    reference : ndarray (m_s,), optional
        The source's closure of each of its pairs in the shape that closes the opening by definition
        (``eyeBlinkLeft`` for ``eye_L``; :func:`with_references`): closures are measured against it.
    """

    name: str
    source_pairs: np.ndarray
    source_t: np.ndarray
    target_pairs: np.ndarray
    target_t: np.ndarray
    mode: str = "ratio"
    scale: float = 1.0
    reference: np.ndarray | None = None     # (m_s,) the source's closure in its own full-closing shape


def _arc(verts, path):
    seg = np.linalg.norm(np.diff(verts[path], axis=0), axis=1)
    s = np.r_[0.0, np.cumsum(seg)]
    return s / s[-1] if s[-1] > 0 else np.linspace(0.0, 1.0, len(path))


def facing_pairs(verts: ArrayLike, upper: Sequence[int], lower: Sequence[int]) -> tuple:
    """Pair each interior vertex of the upper contour with the lower contour's vertex nearest in arc length.

    Parameters
    ----------
    verts : array_like (n, 3)
    upper, lower : sequence of int
        Vertex paths from the same corner to the same other corner (the corners may be shared).

    Returns
    -------
    pairs : ndarray of int (m, 2)
        (upper, lower); pairs whose two vertices coincide (shared corners) are left out.
    t : ndarray (m,)
        Arc-length parameter of each pair's upper vertex.
    """
    V = np.asarray(verts, dtype=np.float64)
    up, lo = np.asarray(upper, dtype=np.int64), np.asarray(lower, dtype=np.int64)
    if up.size < 2 or lo.size < 2:
        raise ShapeSpaceError(f"a contour needs at least 2 vertices (upper {up.size}, lower {lo.size})",
                              ErrorCode.SHAPE)
    tu, tl = _arc(V, up), _arc(V, lo)
    j = np.clip(np.searchsorted(tl, tu), 0, lo.size - 1)
    jm = np.clip(j - 1, 0, lo.size - 1)
    j = np.where(np.abs(tl[jm] - tu) < np.abs(tl[j] - tu), jm, j)
    pairs = np.c_[up, lo[j]]
    keep = pairs[:, 0] != pairs[:, 1]
    return pairs[keep], tu[keep]


SHUT = 0.05          # an opening whose median gap is below this × its contour length is shut at rest


def _length(verts, path):
    return float(np.linalg.norm(np.diff(verts[np.asarray(path)], axis=0), axis=1).sum())


def _spread(t):
    """Arc-length parameters stretched over [0, 1]: two contours may share their first or last edges (the
    pairs there coincide and are left out), and the opening proper is what lies between; ICT FaceKit's named
    lid contours share their first third."""
    span = float(t.max() - t.min()) if t.size else 0.0
    return (t - t.min()) / span if span > 0 else np.zeros_like(t)


def opening(name: str, src_verts: ArrayLike, src_upper: Sequence[int], src_lower: Sequence[int],
            dst_verts: ArrayLike, dst_upper: Sequence[int], dst_lower: Sequence[int]) -> Opening:
    """An :class:`Opening` from the two heads' contour paths (same corner first on both heads); ``offset``
    mode when either head's opening is shut at rest (median gap below :data:`SHUT` × contour length)."""
    S, T = np.asarray(src_verts, dtype=np.float64), np.asarray(dst_verts, dtype=np.float64)
    sp_, st = facing_pairs(S, src_upper, src_lower)
    tp, tt = facing_pairs(T, dst_upper, dst_lower)
    if sp_.shape[0] == 0 or tp.shape[0] == 0:
        raise ShapeSpaceError(f"opening {name}: the upper and lower contours coincide", ErrorCode.DEGENERATE)
    st, tt = _spread(st), _spread(tt)
    ls, lt = _length(S, src_upper), _length(T, dst_upper)
    shut = any(np.median(np.linalg.norm(V[p[:, 0]] - V[p[:, 1]], axis=1)) < SHUT * length
               for V, p, length in ((S, sp_, ls), (T, tp, lt)))
    return Opening(name, sp_, st, tp, tt, "offset" if shut else "ratio", lt / ls if ls > 0 else 1.0)


#: The openings made from named landmark contours: (name, upper contour, lower contour).
OPENINGS = (("eye_L", "lid_upper_L", "lid_lower_L"), ("eye_R", "lid_upper_R", "lid_lower_R"),
            ("mouth", "lip_upper_inner", "lip_lower_inner"))


def openings_from_named(src_verts: ArrayLike, src_tris: ArrayLike, src_marks: dict, dst_verts: ArrayLike,
                        dst_tris: ArrayLike, dst_marks: dict) -> list:
    """Every :data:`OPENINGS` whose contours' landmarks are named on both heads
    (:func:`core.authoring.named.contour_paths`), as :class:`Opening` objects."""
    cs = contour_paths(src_verts, src_tris, src_marks)
    ct = contour_paths(dst_verts, dst_tris, dst_marks)
    return [opening(name, src_verts, cs[up], cs[lo], dst_verts, ct[up], ct[lo]) for name, up, lo in OPENINGS
            if up in cs and lo in cs and up in ct and lo in ct]


def constraint_matrix(openings: Sequence[Opening], n_t: int) -> sp.csr_matrix:
    """``C`` (m, n_t): row ``i`` is ``e_u − e_l`` of target pair ``i`` over all openings, in order."""
    pairs = np.concatenate([o.target_pairs for o in openings]) if openings else np.zeros((0, 2), np.int64)
    m = pairs.shape[0]
    rows = np.r_[np.arange(m), np.arange(m)]
    vals = np.r_[np.ones(m), -np.ones(m)]
    return sp.csr_matrix((vals, (rows, pairs.T.ravel())), shape=(m, n_t))


def closures(openings: Sequence[Opening], src_verts: np.ndarray, src_deltas: np.ndarray) -> np.ndarray:
    """The source's closure of every target pair, per shape: (k, m) (see the module docstring)."""
    out = []
    for o in openings:
        u, lo = o.source_pairs[:, 0], o.source_pairs[:, 1]
        G = src_verts[u] - src_verts[lo]                                   # (m_s, 3)
        G2 = G[None] + src_deltas[:, u] - src_deltas[:, lo]                # (k, m_s, 3)
        c = 1.0 - np.einsum("kmi,mi->km", G2, G) / np.maximum(np.sum(G * G, axis=1), 1e-300)
        if o.reference is not None:                       # against the source's own full closure, within ±1
            c = np.clip(c / np.where(o.reference >= REFERENCE_MIN, o.reference, 1.0), -1.0, 1.0)
        out.append(np.stack([np.interp(o.target_t, o.source_t, ck) for ck in c]) if c.shape[0] else
                   np.zeros((0, o.target_t.size)))
    return np.concatenate(out, axis=1) if out else np.zeros((src_deltas.shape[0], 0))


#: A source pair whose closure in the full-closing shape is below this is not normalised by it (a corner
#: that does not move); normalised closures are clipped to ±1.
REFERENCE_MIN = 0.02
#: The shape that closes each opening by definition (ARKit: the eye is shut at eyeBlink = 1).
CLOSING = {"eye_L": "eyeBlinkLeft", "eye_R": "eyeBlinkRight"}


def with_references(openings: Sequence[Opening], src_verts: np.ndarray, src_deltas: np.ndarray,
                    names: Sequence[str]) -> list:
    """The openings with their :attr:`Opening.reference` set from the source's closing shape (:data:`CLOSING`,
    by canonical name).  The source's lid contours are where an artist (or the proposal) put them, which need
    not be exactly where its lids meet: ICT FaceKit's own blink shuts its named lid contours to a third of the
    gap only.  Measured against its own blink, a source's closures mean "shut" where its blink shuts, and a
    target closes over its own gap as far as the source's eye closes.  Measured with the shared heads' named
    contours (blink gap left, widest over widest open): ICT FaceKit → FBHead 0.73 → 0.015, FBHead → Ready
    Player Me 0.27 → 0.021, Ready Player Me → Face Cap 0.25 → 0.005, the joint relative error unchanged."""
    canon = [canonical_name(n) for n in names]
    out = []
    for o in openings:
        name = CLOSING.get(o.name)
        if name is None or name not in canon:
            out.append(o)
            continue
        ref = closures([replace(o, reference=None, target_t=o.source_t)], src_verts,
                       src_deltas[canon.index(name)][None])[0]
        out.append(replace(o, reference=ref))
    return out


def gap_changes(openings: Sequence[Opening], src_verts: np.ndarray, src_deltas: np.ndarray,
                dst_verts: np.ndarray) -> np.ndarray:
    """The change ``d_u − d_l = −min(c, 1) · (u − l)`` every target pair of the (``ratio``) openings must make,
    per shape: (k, m, 3), with the source's closure ``c`` at the pair's arc length (:func:`closures`).  A source
    whose lids pass each other (``c > 1``: Face Cap's blink) makes the target's meet, not cross."""
    out = []
    for o in openings:
        G_t = dst_verts[o.target_pairs[:, 0]] - dst_verts[o.target_pairs[:, 1]]
        out.append(-np.minimum(closures([o], src_verts, src_deltas), 1.0)[:, :, None] * G_t[None])
    return np.concatenate(out, axis=1) if out else np.zeros((src_deltas.shape[0], 0, 3))


def carried(openings: Sequence[Opening]) -> list:
    """The openings whose closure the transfer carries: those open at rest (``ratio``).  An opening shut at
    rest (lips that touch) is checked (:mod:`.quality`: lips that meet) but not carried: carrying the
    source's change of its gap, scaled by the contours' length ratio, made the transfer worse on the shared
    heads (joint relative error FBHead → Ready Player Me 0.577 → 0.816, Face Cap → Ready Player Me 0.687 →
    0.913), and so did constraining it only for the shapes whose source lips stay shut (0.577 → 0.579 with
    more lips failing the check): the inner-lip contours of two heads do not correspond closely enough."""
    return [o for o in openings if o.mode == "ratio"]


def gap_fractions(verts: np.ndarray, deltas: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """Signed remaining gap of each pair as a fraction of its neutral gap, (k, m): 1 open as at rest, 0 shut,
    negative crossed (the upper side passed the lower)."""
    G = verts[pairs[:, 0]] - verts[pairs[:, 1]]
    G2 = G[None] + deltas[:, pairs[:, 0]] - deltas[:, pairs[:, 1]]
    return np.einsum("kmi,mi->km", G2, G) / np.maximum(np.sum(G * G, axis=1), 1e-300)


def gap_left(verts: np.ndarray, deltas: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """The opening's widest remaining gap over its widest open gap, per shape (k,): 0 shut, 1 as open as at
    rest (the corners' small gaps do not dominate, as they would in per-pair fractions)."""
    G = verts[pairs[:, 0]] - verts[pairs[:, 1]]
    G2 = G[None] + deltas[:, pairs[:, 0]] - deltas[:, pairs[:, 1]]
    return np.linalg.norm(G2, axis=2).max(axis=1) / max(float(np.linalg.norm(G, axis=1).max()), 1e-300)
