"""Landmark pairs between two heads (thesis 3.4.1 / 3.5.4): hand-placed, from shared shapes, validated.

- :class:`LandmarkPairs` — matching points on the source and target neutral (vertex indices when known);
- :func:`landmarks_from_indices`, :func:`landmarks_from_points` — from the artist's picks;
- :func:`check_landmarks` — refuse pairs that cannot determine a warp (fewer than 5, collinear,
  coincident, all on one side of the head), with one line naming the problem;
- :func:`landmarks_from_shared_shapes` — pairs from the shapes both rigs share: for each shared shape the
  source vertex that moves most, matched to the target vertex (among those the same shape moves strongly)
  whose normalised displacement *signature* across all shared shapes is closest.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from .. import validate
from ..errors import ErrorCode
from ..names import canonical_name
from ..result import Result, ShapeSpaceError, Status
from .mesh import bbox_diagonal, symmetry_plane

__all__ = ["MIN_LANDMARKS", "LandmarkPairs", "landmarks_from_indices", "landmarks_from_points", "check_landmarks",
           "landmarks_from_shared_shapes", "layout"]

#: Fewest landmark pairs a registration accepts (a similarity needs 3; the thin-plate warp's affine part 4;
#: one more so that a single misplaced landmark cannot go unnoticed).
MIN_LANDMARKS = 5


@dataclass
class LandmarkPairs:
    """Matching points on two neutral meshes.

    Attributes
    ----------
    source, target : ndarray, shape (m, 3)
        Points on the source and the target neutral.
    source_index, target_index : ndarray of int, shape (m,)
        Vertex index of each point, −1 for a free surface point.
    names : tuple of str, length m
    confidence : ndarray of float, shape (m,)
        How sure a proposal is of each pair, 0…1 (1 for pairs placed by hand).
    flagged : ndarray of bool, shape (m,)
        Pairs a proposal is unsure of: shown to the artist to check, left out by :meth:`unflagged`.
    """

    source: np.ndarray
    target: np.ndarray
    source_index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    target_index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    names: tuple = ()
    confidence: np.ndarray = field(default_factory=lambda: np.zeros(0))
    flagged: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    def __post_init__(self):
        m = np.asarray(self.source).shape[0] if np.ndim(self.source) == 2 else 0
        if len(self.source_index) == 0:
            self.source_index = np.full(m, -1, dtype=int)
        if len(self.target_index) == 0:
            self.target_index = np.full(m, -1, dtype=int)
        if not self.names:
            self.names = tuple(f"L{i}" for i in range(m))
        if len(self.confidence) == 0:
            self.confidence = np.ones(m)
        if len(self.flagged) == 0:
            self.flagged = np.zeros(m, dtype=bool)

    def unflagged(self) -> LandmarkPairs:
        """The pairs not flagged as unsure (all of them when none is flagged)."""
        keep = ~np.asarray(self.flagged, dtype=bool)
        return LandmarkPairs(np.asarray(self.source)[keep], np.asarray(self.target)[keep],
                             np.asarray(self.source_index)[keep], np.asarray(self.target_index)[keep],
                             tuple(n for n, k in zip(self.names, keep) if k), np.asarray(self.confidence)[keep],
                             np.zeros(int(keep.sum()), dtype=bool))

    def __len__(self) -> int:
        return int(np.asarray(self.source).shape[0])

    def to_json(self) -> dict:
        """Plain lists (for stored data)."""
        return {"source": np.asarray(self.source).tolist(), "target": np.asarray(self.target).tolist(),
                "source_index": [int(i) for i in self.source_index],
                "target_index": [int(i) for i in self.target_index], "names": list(self.names),
                "confidence": [float(c) for c in self.confidence], "flagged": [bool(f) for f in self.flagged]}

    @classmethod
    def from_json(cls, data: dict) -> LandmarkPairs:
        """Inverse of :meth:`to_json`."""
        try:
            return cls(np.asarray(data["source"], dtype=np.float64).reshape(-1, 3),
                       np.asarray(data["target"], dtype=np.float64).reshape(-1, 3),
                       np.asarray(data["source_index"], dtype=int), np.asarray(data["target_index"], dtype=int),
                       tuple(data["names"]), np.asarray(data.get("confidence", []), dtype=np.float64),
                       np.asarray(data.get("flagged", []), dtype=bool))
        except (KeyError, TypeError, ValueError) as exc:
            raise ShapeSpaceError(f"stored landmarks are damaged: {exc}", ErrorCode.CORRUPT_METADATA) from None


def landmarks_from_indices(src_verts: ArrayLike, dst_verts: ArrayLike, src_index: ArrayLike, dst_index: ArrayLike,
                           names: Sequence[str] | None = None) -> LandmarkPairs:
    """Landmark pairs from vertex indices picked on both meshes.

    Parameters
    ----------
    src_verts : array_like (n_s, 3)
    dst_verts : array_like (n_t, 3)
    src_index, dst_index : array_like of int (m,)
    names : sequence of str, optional

    Returns
    -------
    LandmarkPairs
    """
    S = validate.array(src_verts, "source vertices", shape=(None, 3))
    T = validate.array(dst_verts, "target vertices", shape=(None, 3))
    si = np.asarray(src_index, dtype=np.int64).ravel()
    ti = np.asarray(dst_index, dtype=np.int64).ravel()
    if si.shape != ti.shape:
        raise ShapeSpaceError(f"{si.size} source landmark vertices but {ti.size} target ones", ErrorCode.SHAPE)
    for idx, V, side in ((si, S, "source"), (ti, T, "target")):
        bad = (idx < 0) | (idx >= V.shape[0])
        if bad.any():
            k = int(np.argmax(bad))
            raise ShapeSpaceError(f"landmark {k} names {side} vertex {int(idx[k])} but the {side} mesh has "
                                  f"{V.shape[0]} vertices", ErrorCode.RANGE)
    names = tuple(names) if names is not None else ()
    return LandmarkPairs(S[si].copy(), T[ti].copy(), si, ti, names)


def landmarks_from_points(src_points: ArrayLike, dst_points: ArrayLike,
                          names: Sequence[str] | None = None) -> LandmarkPairs:
    """Landmark pairs from free surface points (m, 3) on both meshes (e.g. snapped picks)."""
    S = validate.array(src_points, "source landmarks", shape=(None, 3))
    T = validate.array(dst_points, "target landmarks", shape=(None, 3))
    if S.shape != T.shape:
        raise ShapeSpaceError(f"{S.shape[0]} source landmarks but {T.shape[0]} target ones", ErrorCode.SHAPE)
    return LandmarkPairs(S.copy(), T.copy(), names=tuple(names) if names is not None else ())


def layout(points: ArrayLike, rel_tol: float = 1e-3) -> str:
    """``"collinear"``, ``"coplanar"`` or ``"spatial"``: the spread of points (m, 3), judged by the singular
    values of the centred points relative to the largest."""
    X = np.asarray(points, dtype=np.float64)
    sv = np.linalg.svd(X - X.mean(axis=0), compute_uv=False)
    if sv.size < 2 or sv[0] == 0 or sv[1] <= rel_tol * sv[0]:
        return "collinear"
    if sv.size < 3 or sv[2] <= rel_tol * sv[0]:
        return "coplanar"
    return "spatial"


def _sides(points, verts):
    """Left/centre/right (−1/0/+1) of each point relative to the mesh's mirror plane, or None if the mesh has
    no clear mirror plane."""
    normal, offset, err = symmetry_plane(verts)
    if err > 0.02:
        return None
    sd = points @ normal - offset
    band = 0.03 * bbox_diagonal(verts)
    return np.where(sd > band, 1, np.where(sd < -band, -1, 0))


def check_landmarks(pairs: LandmarkPairs, src_verts: ArrayLike | None = None,
                    dst_verts: ArrayLike | None = None) -> None:
    """Refuse landmark pairs that cannot determine a registration (one line naming the problem).

    Checks: equal (m, 3) shapes, finite, m ≥ :data:`MIN_LANDMARKS`, no two landmarks at one point, not all
    on one line, and — when the meshes are given and have a clear mirror plane — not all on one side of
    the head.

    Raises
    ------
    ShapeSpaceError
        Codes ``shape``, ``non_finite``, ``too_few_landmarks``, ``degenerate``, ``collinear``.
    """
    S = validate.array(pairs.source, "source landmarks", shape=(None, 3))
    T = validate.array(pairs.target, "target landmarks", shape=(None, 3))
    if S.shape != T.shape:
        raise ShapeSpaceError(f"{S.shape[0]} source landmarks but {T.shape[0]} target ones", ErrorCode.SHAPE)
    m = S.shape[0]
    if m < MIN_LANDMARKS:
        raise ShapeSpaceError(f"{m} landmark pair{'s' if m != 1 else ''} given; model transfer needs at least "
                              f"{MIN_LANDMARKS} (eye corners, nose tip, mouth corners, chin)",
                              ErrorCode.TOO_FEW_LANDMARKS)
    names = list(pairs.names) if len(pairs.names) == m else [f"L{i}" for i in range(m)]
    for P, side in ((S, "source"), (T, "target")):
        scale = max(float(np.ptp(P, axis=0).max()), 1e-300)
        d = np.linalg.norm(P[:, None, :] - P[None, :, :], axis=2)
        np.fill_diagonal(d, np.inf)
        i, j = np.unravel_index(int(np.argmin(d)), d.shape)
        if d[i, j] <= 1e-6 * scale:
            raise ShapeSpaceError(f"landmarks {names[i]!r} and {names[j]!r} are at the same point on the {side}: "
                                  f"move or delete one", ErrorCode.DEGENERATE)
        if layout(P) == "collinear":
            raise ShapeSpaceError(f"the {side} landmarks lie on one line: add landmarks off that line (eye "
                                  f"corners and the chin, not only the mouth)", ErrorCode.COLLINEAR)
    for P, V, side in ((S, src_verts, "source"), (T, dst_verts, "target")):
        if V is None:
            continue
        sides = _sides(P, validate.array(V, f"{side} vertices", shape=(None, 3)))
        if sides is not None and (not (sides > 0).any() or not (sides < 0).any()):
            where = "on its centre line" if not sides.any() else "on one side"
            raise ShapeSpaceError(f"all {m} landmarks are {where} of the {side} head: add landmarks on both "
                                  f"sides (both eye and mouth corners)", ErrorCode.DEGENERATE)


def _signatures(deltas, mask):
    mag = np.linalg.norm(deltas, axis=2)                       # (k, n)
    mag = np.where(mask[None, :], mag, 0.0)
    peak = mag.max(axis=1, keepdims=True)
    rel = mag / np.where(peak > 0, peak, 1.0)                  # (k, n) in [0, 1]
    sig = rel.T                                                # (n, k)
    norm = np.linalg.norm(sig, axis=1, keepdims=True)
    return rel, sig / np.where(norm > 0, norm, 1.0)


def landmarks_from_shared_shapes(src_verts: ArrayLike, src_deltas: ArrayLike, src_names: Sequence[str],
                                 dst_verts: ArrayLike, dst_deltas: ArrayLike, dst_names: Sequence[str], *,
                                 src_mask: ArrayLike | None = None, dst_mask: ArrayLike | None = None,
                                 strong: float = 0.6, rel_tol: float = 0.05) -> Result:
    """Landmark pairs from the shapes two rigs share (matched by canonical ARKit name).

    For each shared shape that moves both meshes, the source vertex ``a`` that moves most; on the target,
    among the vertices the same shape moves by at least ``strong`` × its peak, the one whose signature —
    the vector of its displacement magnitudes over all shared shapes, each divided by that shape's peak,
    normalised — is closest to ``a``'s.  Each vertex is used once.

    Parameters
    ----------
    src_verts : array_like (n_s, 3)
    src_deltas : array_like (k_s, n_s, 3)
    src_names : sequence of str (k_s,)
    dst_verts, dst_deltas, dst_names : the same for the target
    src_mask, dst_mask : array_like of bool (n,), optional
        Vertices allowed as landmarks (e.g. the skin part only, not the eyeballs).
    strong : float
        Target candidates must move at least this fraction of the shape's peak.
    rel_tol : float
        Shapes whose peak is below ``rel_tol`` × the rig's largest are skipped (empty or faint).

    Returns
    -------
    Result
        ``value``: :class:`LandmarkPairs` (names = the shapes used); ``diagnostics["shapes_used"]``,
        ``["shapes_skipped"]``.  FAILED when fewer than :data:`MIN_LANDMARKS` pairs come out.
    """
    SV = validate.array(src_verts, "source vertices", shape=(None, 3))
    TV = validate.array(dst_verts, "target vertices", shape=(None, 3))
    SD = validate.array(src_deltas, "source deltas", shape=(None, SV.shape[0], 3))
    TD = validate.array(dst_deltas, "target deltas", shape=(None, TV.shape[0], 3))
    if len(src_names) != SD.shape[0] or len(dst_names) != TD.shape[0]:
        raise ShapeSpaceError("one name per shape is needed on both rigs", ErrorCode.SHAPE)
    sm = np.ones(SV.shape[0], bool) if src_mask is None else np.asarray(src_mask, bool)
    tm = np.ones(TV.shape[0], bool) if dst_mask is None else np.asarray(dst_mask, bool)
    t_by = {}
    for j, n in enumerate(dst_names):
        t_by.setdefault(canonical_name(n), j)
    pairs = [(i, t_by[canonical_name(n)]) for i, n in enumerate(src_names) if canonical_name(n) in t_by]
    if not pairs:
        return Result(None, status=Status.FAILED, message="the two rigs share no shape names",
                      diagnostics={"shapes_used": [], "shapes_skipped": []})
    si = np.array([p[0] for p in pairs])
    ti = np.array([p[1] for p in pairs])
    rel_s, sig_s = _signatures(SD[si], sm)
    rel_t, sig_t = _signatures(TD[ti], tm)
    peak_s = np.linalg.norm(SD[si], axis=2).max(axis=1)
    peak_t = np.linalg.norm(TD[ti], axis=2).max(axis=1)
    src_idx, dst_idx, used, skipped = [], [], [], []
    for k in np.argsort(-(peak_s / max(peak_s.max(), 1e-300))):
        name = canonical_name(src_names[si[k]])
        if peak_s[k] < rel_tol * peak_s.max() or peak_t[k] < rel_tol * peak_t.max():
            skipped.append(name)
            continue
        a = int(np.argmax(rel_s[k]))
        cand = np.flatnonzero(rel_t[k] >= strong)
        cand = cand[~np.isin(cand, dst_idx)]
        if a in src_idx or cand.size == 0:
            skipped.append(name)
            continue
        b = int(cand[np.argmin(np.linalg.norm(sig_t[cand] - sig_s[a], axis=1))])
        src_idx.append(a)
        dst_idx.append(b)
        used.append(name)
    diag = {"shapes_used": used, "shapes_skipped": skipped}
    if len(used) < MIN_LANDMARKS:
        return Result(None, status=Status.FAILED, diagnostics=diag,
                      message=f"only {len(used)} shared shapes move both heads; place landmarks by hand")
    lm = LandmarkPairs(SV[src_idx].copy(), TV[dst_idx].copy(), np.array(src_idx), np.array(dst_idx), tuple(used))
    return Result(lm, message=f"{len(used)} landmarks from shared shapes", diagnostics=diag)
