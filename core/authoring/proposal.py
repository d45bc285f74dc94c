"""Automatic landmark proposal for a target head that has no shapes (issue #13 §1).

The source rig's shapes tell where its landmarks are (the vertex each shape moves most: eyelid, mouth
corner, chin, brow …; strongest shapes first, none closer than 2 % of the head's diagonal to another).
The target has no shapes, so its landmarks are found geometrically:

1. each head gets a frame from its mirror plane (:func:`~core.authoring.mesh.symmetry_plane`: the normal is
   the left–right axis) and the two principal axes of its vertices within that plane;
2. the frames are matched under the 8 proper rotations that keep the left–right axis an axis (in-plane
   quarter turns, and the half turn that swaps left and right) and three starting scales, each refined by
   similarity ICP of the whole skin (Umeyama on closest points, the worst 30 % of pairs trimmed);
3. each fit is then refined on the source's *face* — the skin its shapes move (≥ 10 % of a shape's peak) —
   alone (10 % trimmed, pairs whose vertex normals are 90° or more apart dropped, the scale kept within
   ×0.7…×1.43 of the whole-skin fit, so the face cannot shrink onto a patch);
4. the fit with the smallest score wins: the face's trimmed RMS distance to the target plus the trimmed RMS
   distance from the target to the moved source skin over the target points the source *covers* (those
   whose closest source vertex is not on the source's open border);
5. each source landmark, moved by that similarity, is snapped to the nearest target vertex that faces the
   same way (normals less than 90° apart; else the nearest).

Why steps 3 to 5: heads differ beyond the face (a face mask against a whole head with neck and back of the
head, longer necks, other skull shapes, an inner mouth).  A whole-skin fit then places the face by the
skull and neck and misses it by 1–1.5 cm (FBHead → ICT FaceKit), and a score measured both ways over the
whole of both heads prefers the mask on the *back* of a whole head (facecap → ICT: 60 mm off), because the
target's extra surface is far from the source wherever the source goes.  The face is what landmarks are on
and what shapes move; the target surface the source does not reach says nothing about the fit.  Closest
points that face the other way are the inside of the lips and ICT's mouth socket just behind them: without
the normal test the lips and chin were pulled onto them and landmarks snapped there.  Measured on the shared
heads (median distance of the proposed target landmarks to the ones found from the shapes both rigs share,
per shape name, mm at a 30 cm head; before → now): facecap → ICT 62 → 3.0, FBHead → ICT 8.0 → 3.1,
ICT → facecap 62 → 5.6, ICT → FBHead 6.1 → 4.7, facecap → FBHead 1.9 → 1.0, FBHead → facecap 1.7 → 3.3.
Spacing: near-duplicate landmarks (eyeBlink and eyeLookUp on one eyelid) that snap a few mm apart shear the
landmark warp locally; with 2 % the mean relative transfer error with proposed landmarks
(``tools/bench_transfer.py``, ``transfer_rel_auto_*``) was facecap → FBHead 0.80 instead of 0.91, the other
pairs within ±0.02.

Named landmarks (issue #22 §3, ``named=True``): when the source's ARKit shapes locate the 26
named landmarks (:func:`~core.authoring.features.locate_from_shapes`), those are proposed instead: moved by the
winning similarity, snapped, then re-found on the target's own features
(:func:`~core.authoring.features.locate_on_geometry`: the eye openings' rims for the corners and lids, the
mouth opening or the lips' contact band for the corners and inner lips, the midline profile in the target's
own landmark frame for nose tip, outer lips and chin).  Each gets a confidence from how far that refinement
moved it (σ = 1.5 % of the diagonal) and how far it is from the mirror image of its partner beyond the
target's own asymmetry (σ = 1 %), ×0.45 without a feature (brows, nostrils, jaw angles: always flagged);
below 0.5 it is flagged.  A starting alignment that collapses (a similarity on collinear points) is skipped
and counted (``degenerate_hypotheses``), never the end of the proposal.  Measured
(``tools/bench_landmarks.py``, every other shared head as the source, against ``tools/landmarks/<head>.json``,
mm at a 30 cm head): largest error over the points not flagged facecap 0.0, FBHead 0.0, ICT 1.4, Ready Player
Me 0.0; over all points 32 / 24 / 22 / 30 (the jaw angles, flagged); per source and target 0–14 of the 26
points are left unflagged (an ICT source: the fewest).

Limits: this is a rigid + uniform-scale fit.  The proposal is only as good as the two heads are alike after
scaling (a long-nosed cartoon on a realistic head misplaces mouth and eye corners by the difference); a head
that is far from mirror-symmetric (sculpted asymmetric, posed, with a body attached) can get a wrong frame
(the residual in ``diagnostics`` says how well it fits).  The artist corrects the pairs before registering;
:func:`~core.authoring.registration.register` then refines the whole surface.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree

from .. import validate
from ..result import Result, ShapeSpaceError, Status
from .features import FaceFrame, Head, locate_from_shapes, locate_on_geometry
from .landmarks import MIN_LANDMARKS, LandmarkPairs
from .mesh import bbox_diagonal, boundary_vertices, check_mesh, symmetry_plane, triangle_parts, vertex_normals
from .named import CENTRE, NAMES, mirror_name
from .registration import similarity

__all__ = ["propose_landmark_pairs", "head_frame"]


def head_frame(verts: ArrayLike) -> tuple:
    """A head's frame: centroid (3,) and rotation (3, 3) whose first row is the mirror-plane normal.

    Returns
    -------
    origin : ndarray (3,)
    axes : ndarray (3, 3)
        Rows: mirror normal, first and second in-plane principal axis (right-handed).
    plane_error : float
        Relative mirror residual of :func:`symmetry_plane`.
    """
    V = np.asarray(verts, dtype=np.float64)
    n, _, err = symmetry_plane(V)
    c = V.mean(axis=0)
    X = V - c
    X = X - np.outer(X @ n, n)
    _, _, vt = np.linalg.svd(X, full_matrices=False)
    a = vt[0] - (vt[0] @ n) * n
    a /= np.linalg.norm(a)
    return c, np.stack([n, a, np.cross(n, a)]), err


def _hypotheses():
    out = []
    for flip in (1.0, -1.0):
        for k in range(4):
            ang = k * np.pi / 2
            c, s = np.cos(ang), np.sin(ang)
            rot = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
            if flip < 0:
                rot = np.diag([-1.0, 1.0, -1.0]) @ rot
            out.append(rot)
    return out


def _trimmed_rms(d, trim):
    keep = d <= np.quantile(d, 1.0 - trim)
    return float(np.sqrt(np.mean(d[keep] ** 2)))


def _similarity_icp(S, T, tree, s, R, t, iterations, trim):
    """Similarity ICP of S onto T; the score is the trimmed RMS in BOTH directions (a source shrunk onto a
    patch of the target fits one way only)."""
    for _ in range(iterations):
        moved = s * S @ R.T + t
        d, idx = tree.query(moved)
        keep = d <= np.quantile(d, 1.0 - trim)
        s, R, t = similarity(S[keep], T[idx[keep]])
    moved = s * S @ R.T + t
    there = _trimmed_rms(tree.query(moved)[0], trim)
    back = _trimmed_rms(cKDTree(moved).query(T)[0], trim)
    return s, R, t, max(there, back)


def _face_refine(F, FN, T, TN, tree, s, R, t, iterations, trim, bounds):
    """Similarity ICP of the face points F (normals FN) onto the target points T (normals TN, tree over T): pairs
    whose normals are 90° or more apart are dropped (the inside of the lips, the mouth socket), the scale is kept
    within ``bounds`` × the starting scale."""
    lo, hi = bounds[0] * s, bounds[1] * s
    for _ in range(iterations):
        d, idx = tree.query(s * F @ R.T + t)
        keep = (d <= np.quantile(d, 1.0 - trim)) & (np.einsum("ij,ij->i", FN @ R.T, TN[idx]) > 0.0)
        X, Y = F[keep], T[idx[keep]]
        if X.shape[0] < 3:
            break
        s, R, t = similarity(X, Y)
        s = float(np.clip(s, lo, hi))
        t = Y.mean(axis=0) - s * R @ X.mean(axis=0)
    return s, R, t


def _covered_rms(moved_skin, border, Ts, trim):
    """Trimmed RMS distance from the target points to the moved source skin, over the target points whose
    closest source vertex is not on the source's open border (the part of the target the source covers)."""
    d, j = cKDTree(moved_skin).query(Ts)
    inside = ~border[j]
    if inside.sum() < 10:
        return np.inf
    return _trimmed_rms(d[inside], trim)


def _snap_facing(points, normals, T, t_normals, tree, k):
    """For each point (m, 3) with its normal, the index into T of the nearest of its ``k`` closest vertices
    whose normal is less than 90° from it (else the closest)."""
    k = max(1, min(int(k), T.shape[0]))
    _, j = tree.query(points, k=k)
    j = j.reshape(len(points), k)
    facing = np.einsum("mkc,mc->mk", t_normals[j], normals) > 0.0
    first = np.where(facing.any(axis=1), np.argmax(facing, axis=1), 0)
    return j[np.arange(len(points)), first]


def propose_landmark_pairs(src_verts: ArrayLike, src_tris: ArrayLike, src_deltas: ArrayLike,
                           src_names: Sequence[str], dst_verts: ArrayLike, dst_tris: ArrayLike, *,
                           iterations: int = 25, trim: float = 0.3, sample: int = 2500, face: float = 0.1,
                           face_trim: float = 0.1, scale_bounds: tuple = (0.7, 1.43), snap: int = 16,
                           spacing: float = 0.02, named: bool = False, flag: float = 0.5) -> Result:
    """Landmark pairs for a target head without shapes, proposed from the source rig's shapes and geometry.

    Parameters
    ----------
    src_verts : array_like (n_s, 3)
    src_tris : array_like of int (f_s, 3)
    src_deltas : array_like (k, n_s, 3)
    src_names : sequence of str (k,)
    dst_verts : array_like (n_t, 3)
    dst_tris : array_like of int (f_t, 3)
    iterations : int
        Similarity-ICP iterations per hypothesis.
    trim : float
        Fraction of the worst closest-point pairs ignored (parts one head has and the other has not).
    sample : int
        Vertices used per head for the fit.
    face : float
        The source's face: skin vertices some shape moves by at least this fraction of its peak.
    face_trim : float
        Fraction of the worst pairs ignored when refining on the face and scoring a fit.
    scale_bounds : (float, float)
        The face refinement keeps the scale within these factors of the whole-skin fit's.
    spacing : float
        Source landmarks closer than this × the source's diagonal to a landmark of a stronger shape are
        dropped (two landmarks a few mm apart add nothing but a chance of disagreeing, which the landmark
        warp turns into a local shear).
    snap : int
        A moved source landmark snaps to the nearest of this many closest target vertices that faces the same
        way (vertex normals at less than 90°), else to the closest: not to the inside of the lips or the mouth
        socket behind them.

    named : bool
        Propose the named landmarks (:mod:`.named`) when the source's ARKit shapes locate them (eyeBlink,
        mouthPucker …; else, and by default, one landmark per strong source shape, named after it).  Register
        with ``value.unflagged()`` to leave out the ones it is unsure of.
    flag : float
        Named landmarks whose confidence is below this are flagged (``LandmarkPairs.flagged``).

    Returns
    -------
    Result
        ``value``: :class:`LandmarkPairs` — the named landmarks with ``confidence`` and ``flagged`` per
        pair, or (see ``named``) pairs named after the source shapes; ``diagnostics``: ``flagged`` (names),
        ``degenerate_hypotheses`` (starting alignments skipped because they collapsed), ``fit_residual``
        (the larger of the face's and the covered target's trimmed RMS distance / target diagonal),
        ``similarity`` ``(s, R, t)``, ``plane_error`` (source, target).
        WARNING when the fit residual exceeds 2 % of the diagonal or a head has no clear mirror plane;
        FAILED when fewer than 5 source shapes move the skin.
    """
    S, ST = check_mesh(src_verts, src_tris, "source")
    T, TT = check_mesh(dst_verts, dst_tris, "target")
    D = validate.array(src_deltas, "source deltas", shape=(None, S.shape[0], 3))
    s_part, _ = triangle_parts(S.shape[0], ST)
    t_part, _ = triangle_parts(T.shape[0], TT)
    skin_s, skin_t = np.flatnonzero(s_part == 0), np.flatnonzero(t_part == 0)
    mag = np.linalg.norm(D[:, skin_s], axis=2) if D.shape[0] else np.zeros((0, skin_s.size))
    peak = mag.max(axis=1) if mag.size else np.zeros(0)
    idx, names = [], []
    gap = spacing * bbox_diagonal(S[skin_s]) if skin_s.size else 0.0
    for k in np.argsort(-peak):
        if peak[k] <= 0.05 * peak.max():
            continue
        v = int(skin_s[np.argmax(mag[k])])
        if v not in idx and (not idx or np.linalg.norm(S[idx] - S[v], axis=1).min() >= gap):
            idx.append(v)
            names.append(str(src_names[k]))
    if len(idx) < MIN_LANDMARKS:
        return Result(None, status=Status.FAILED,
                      message=f"only {len(idx)} source shapes move the skin: place landmarks by hand")
    rng = np.random.default_rng(0)
    Ss = S[skin_s] if skin_s.size <= sample else S[rng.choice(skin_s, sample, replace=False)]
    Ts = T[skin_t] if skin_t.size <= sample else T[rng.choice(skin_t, sample, replace=False)]
    cs, As, es = head_frame(S[skin_s])
    ct, At, et = head_frame(T[skin_t])
    scale = bbox_diagonal(T[skin_t]) / max(bbox_diagonal(S[skin_s]), 1e-300)
    tree = cKDTree(Ts)
    rel_move = (mag / np.where(peak > 0, peak, 1.0)[:, None]).max(axis=0) if mag.size else np.zeros(skin_s.size)
    face_v = skin_s[rel_move >= face]
    if face_v.size < 3 * MIN_LANDMARKS:
        face_v = skin_s
    face_v = face_v if face_v.size <= sample else rng.choice(face_v, sample, replace=False)
    F, FN = S[face_v], vertex_normals(S, ST)[face_v]
    T_skin, TN_skin = T[skin_t], vertex_normals(T, TT)[skin_t]
    skin_tree = cKDTree(T_skin)
    border = boundary_vertices(S.shape[0], ST)[skin_s]
    best, degenerate = None, 0
    for H in _hypotheses():
        for f in (0.75, 1.0, 1.33):
            R0 = At.T @ H @ As
            t0 = ct - f * scale * R0 @ cs
            try:          # one hypothesis can collapse onto a line of target points: skip it, not the proposal
                s0, R1, t1, _ = _similarity_icp(Ss, Ts, tree, f * scale, R0, t0, iterations, trim)
                s1, R1, t1 = _face_refine(F, FN, T_skin, TN_skin, skin_tree, s0, R1, t1, iterations, face_trim,
                                          scale_bounds)
            except ShapeSpaceError:
                degenerate += 1
                continue
            there = _trimmed_rms(skin_tree.query(s1 * F @ R1.T + t1)[0], face_trim)
            back = _covered_rms(s1 * S[skin_s] @ R1.T + t1, border, Ts, face_trim)
            if best is None or there + back < best[4]:
                best = (s1, R1, t1, max(there, back), there + back)
    if best is None:
        return Result(None, status=Status.FAILED, diagnostics={"degenerate_hypotheses": degenerate},
                      message="no alignment of the two heads could be fitted (every start collapsed onto a line): "
                              "place landmarks by hand")
    s, R, t, resid, _ = best
    rel = resid / max(bbox_diagonal(T[skin_t]), 1e-300)
    diag = {"fit_residual": rel, "similarity": (s, R, t), "plane_error": (es, et),
            "degenerate_hypotheses": degenerate}
    warn = rel > 0.02 or es > 0.02 or et > 0.02
    pairs = _named_pairs(S, ST, D, src_names, T, TT, (s, R, t), snap, flag, diag) if named else None
    if pairs is None:
        moved = s * S[idx] @ R.T + t
        dst_idx = skin_t[_snap_facing(moved, vertex_normals(S, ST)[idx] @ R.T, T_skin, TN_skin, skin_tree, snap)]
        keep = np.unique(dst_idx, return_index=True)[1]
        keep.sort()
        pairs = LandmarkPairs(S[np.array(idx)[keep]].copy(), T[dst_idx[keep]].copy(), np.array(idx)[keep],
                              dst_idx[keep], tuple(np.array(names)[keep]))
    unsure = [n for n, f in zip(pairs.names, pairs.flagged) if f]
    diag["flagged"] = unsure
    msg = (f"{len(pairs)} landmarks proposed (fit residual {100 * rel:.1f}% of the head size)"
           + (f"; unsure of {len(unsure)} ({', '.join(unsure)}): check them" if unsure else "")
           + ("; check them: the heads do not align well" if warn else ""))
    return Result(pairs, status=Status.WARNING if warn else Status.OK, message=msg, diagnostics=diag)


def _named_pairs(S, ST, D, src_names, T, TT, sim, snap, flag, diagnostics):
    """The named landmarks (:mod:`.named`): found on the source from its shapes, moved onto the target by the
    similarity ``sim``, snapped, and refined on the target's eye and mouth openings and midline profile.

    Confidence per point: ``exp(−(shift / 1.5 %)²) · exp(−(mirror / 1 %)²)``, ×0.45 without a geometric feature
    confirming it — ``shift`` the refinement's distance from the moved source point, ``mirror`` the point's
    distance from the mirror image of its partner on the target (a midline point: twice its distance from
    the target's mirror plane) beyond twice the target's own mean mirror distance, both relative to the
    target's diagonal (``diagnostics["named_shift"]``, ``["named_mirror"]``, ``["named_supported"]``).  Points
    below ``flag`` are flagged.
    None when the source's named landmarks cannot be found from its shapes (no ARKit eye/mouth shapes)."""
    s, R, t = sim
    try:
        src, frame = locate_from_shapes(S, ST, D, src_names)
    except ShapeSpaceError:
        return None
    if len(src) < MIN_LANDMARKS:
        return None
    head = Head.of(T, TT)
    skin_t = np.flatnonzero(head.skin)
    order = [n for n in NAMES if n in src]
    si = np.array([src[n] for n in order])
    moved = s * S[si] @ R.T + t
    tn = head.normals[skin_t]
    rough_idx = skin_t[_snap_facing(moved, vertex_normals(S, ST)[si] @ R.T, T[skin_t], tn, cKDTree(T[skin_t]), snap)]
    t_frame = FaceFrame(s * R @ frame.origin + t, frame.axes @ R.T)
    refined, supported = locate_on_geometry(head, t_frame, dict(zip(order, rough_idx.tolist())))
    ti = np.array([refined[n] for n in order])
    normal, offset, asym = symmetry_plane(T[skin_t])
    P = T[ti]
    mirrored = P - 2.0 * ((P @ normal) - offset)[:, None] * normal
    pos = {n: k for k, n in enumerate(order)}
    mis = np.array([np.linalg.norm(mirrored[pos[mirror_name(n)]] - P[k]) if mirror_name(n) in pos else 0.0
                    for k, n in enumerate(order)])
    mis = np.where([n in CENTRE for n in order], np.abs(P @ normal - offset) * 2.0, mis)
    diag_t = head.diag
    shift = np.linalg.norm(P - moved, axis=1) / diag_t
    excess = np.maximum(mis / diag_t - 2.0 * asym, 0.0)       # beyond the target's own asymmetry
    conf = np.exp(-(shift / 0.015) ** 2) * np.exp(-(excess / 0.01) ** 2)
    conf *= np.where([supported.get(n, False) for n in order], 1.0, 0.45)
    diagnostics.update(named_shift=dict(zip(order, shift.tolist())), named_mirror=dict(zip(order, excess.tolist())),
                       named_supported={n: bool(supported.get(n, False)) for n in order})
    return LandmarkPairs(S[si].copy(), P.copy(), si, ti, tuple(order), conf, conf < flag)
