"""Non-rigid registration of a source neutral onto a target neutral, and the dense map it gives (thesis 3.4.1).

Pipeline (:func:`register`):

1. similarity ``y = s R x + t`` from the landmark pairs (Umeyama's closed form);
2. a thin-plate RBF warp (:mod:`core.rbf`) carrying the landmarks onto their targets (lightly regularised:
   ``warp_smoothing``);
3. parts: each connected part of the target is matched to the source part nearest to it after the warp
   (eyes to eyes, skin to skin); a target part less than 30 % of which lies within ``part_tolerance`` of
   the bounding-box diagonal of the source surface has no counterpart;
4. non-rigid iterative closest points with a smoothness term: with ``Y`` the source vertices, ``Y₀`` the
   warped ones, ``c_i`` the closest target surface point of source vertex ``i`` (restricted to its matched
   target parts; pairs further than ``max_distance``, with opposed normals or on the target's boundary are
   dropped, Amberg et al. 2007) and the landmark term ``ℓ``, each iteration solves the sparse system of

       min_Y  α² ‖L (Y − Y₀)‖² + Σ_i w_i ‖Y_i − c_i‖² + β² Σ_ℓ ‖Y_ℓ − T_ℓ‖² + ε ‖Y − Y₀‖²

   (``L`` the graph Laplacian of the source) for a decreasing stiffness schedule ``α``; at each level the
   accepted pair set is frozen once stable and the level iterates to a tolerance (see :func:`register`);
5. the dense map: for each target vertex and each target triangle's centroid, the closest point on the
   registered source surface (of the matched source part): source triangle and barycentric coordinates.

The residual is the RMS distance of the registered source vertices (those with an accepted closest
point) to the target surface, in mm with the target head scaled to a 30 cm bounding-box diagonal.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike
from scipy.sparse.linalg import splu
from scipy.spatial import cKDTree

from .. import validate
from ..errors import ErrorCode
from ..progress import ProgressFn, notify
from ..rbf import fit_rbf
from ..result import Result, ShapeSpaceError, Status
from .landmarks import LandmarkPairs, check_landmarks, layout
from .mesh import (
    bbox_diagonal,
    boundary_vertices,
    check_mesh,
    closest_on_triangles,
    face_normals,
    mm_per_unit,
    triangle_parts,
    vertex_normals,
)

__all__ = ["Correspondence", "similarity", "register", "warp_points"]


@dataclass
class Correspondence:
    """The dense source ↔ target map of a registration.

    Attributes
    ----------
    registered : ndarray (n_s, 3)
        Source neutral after registration, in target space (the preview mesh).
    tri : ndarray of int (n_t,)
        Source triangle of each target vertex's closest registered source point (−1: no counterpart).
    bary : ndarray (n_t, 3)
        Its barycentric coordinates in that triangle.
    distance : ndarray (n_t,)
        Target vertex → registered source surface distance (target units).
    face_tri : ndarray of int (f_t,)
        Source triangle of each target triangle's centroid (−1: no counterpart).
    similarity : tuple
        ``(s, R (3, 3), t (3,))`` of the landmark fit, source → target.
    target_part : ndarray of int (n_t,)
        Connected part of each target vertex (0 = largest; −1 = in no triangle).
    part_map : dict
        Target part → source part (−1: no counterpart).
    residual_mm : float
        RMS registered-source → target-surface distance over accepted pairs, mm at 30 cm diagonal.
    mm_per_unit : float
        ``300 / target bounding-box diagonal``.
    """

    registered: np.ndarray
    tri: np.ndarray
    bary: np.ndarray
    distance: np.ndarray
    face_tri: np.ndarray
    similarity: tuple
    target_part: np.ndarray
    part_map: dict = field(default_factory=dict)
    residual_mm: float = float("nan")
    mm_per_unit: float = 1.0

    def unmatched_parts(self) -> list:
        """Target parts with no source counterpart, as ``(part, n_vertices, first_vertex)``."""
        out = []
        for p, q in sorted(self.part_map.items()):
            if q < 0:
                idx = np.flatnonzero(self.target_part == p)
                out.append((int(p), int(idx.size), int(idx[0]) if idx.size else -1))
        return out

    def to_json(self) -> dict:
        """Plain lists (for stored data)."""
        s, R, t = self.similarity
        return {"registered": self.registered.tolist(), "tri": self.tri.tolist(), "bary": self.bary.tolist(),
                "distance": self.distance.tolist(), "face_tri": self.face_tri.tolist(),
                "similarity": [float(s), np.asarray(R).tolist(), np.asarray(t).tolist()],
                "target_part": self.target_part.tolist(),
                "part_map": {str(k): int(v) for k, v in self.part_map.items()},
                "residual_mm": float(self.residual_mm), "mm_per_unit": float(self.mm_per_unit)}

    @classmethod
    def from_json(cls, d: dict) -> Correspondence:
        """Inverse of :meth:`to_json`."""
        try:
            s, R, t = d["similarity"]
            return cls(np.asarray(d["registered"], float).reshape(-1, 3), np.asarray(d["tri"], int),
                       np.asarray(d["bary"], float).reshape(-1, 3), np.asarray(d["distance"], float),
                       np.asarray(d["face_tri"], int), (float(s), np.asarray(R, float), np.asarray(t, float)),
                       np.asarray(d["target_part"], int), {int(k): int(v) for k, v in d["part_map"].items()},
                       float(d["residual_mm"]), float(d["mm_per_unit"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise ShapeSpaceError(f"stored correspondence is damaged: {exc}", ErrorCode.CORRUPT_METADATA) from None


def similarity(source: ArrayLike, target: ArrayLike, scaling: bool = True) -> tuple:
    """Best similarity ``target ≈ s R source + t`` (Umeyama 1991).

    With centred ``X``, ``Y`` and ``U Σ Vᵀ = Yᵀ X``: ``R = U diag(1, 1, d) Vᵀ`` (``d = sign det(U Vᵀ)``),
    ``s = tr(Σ diag(1, 1, d)) / ‖X‖²``, ``t = ȳ − s R x̄``.

    Parameters
    ----------
    source, target : array_like (m, 3), m ≥ 3, not collinear

    Returns
    -------
    s : float
    R : ndarray (3, 3)
    t : ndarray (3,)
    """
    X = validate.array(source, "source points", shape=(None, 3))
    Y = validate.array(target, "target points", shape=(X.shape[0], 3))
    if X.shape[0] < 3 or layout(X) == "collinear" or layout(Y) == "collinear":
        raise ShapeSpaceError("a similarity needs at least 3 points not on one line", ErrorCode.COLLINEAR)
    mx, my = X.mean(axis=0), Y.mean(axis=0)
    Xc, Yc = X - mx, Y - my
    U, sv, Vt = np.linalg.svd(Yc.T @ Xc)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    R = U @ D @ Vt
    s = float(np.trace(np.diag(sv) @ D) / np.sum(Xc ** 2)) if scaling else 1.0
    return s, R, my - s * R @ mx


def warp_points(landmarks: LandmarkPairs, points: ArrayLike, smoothing: float = 0.0) -> tuple:
    """Similarity + thin-plate RBF warp carrying the source landmarks exactly onto the target ones.

    With coplanar landmarks (or fewer than 5) the residual warp uses the 3-D biharmonic kernel ``r`` with a
    constant, which they determine, instead of thin plates with an affine part.

    Parameters
    ----------
    landmarks : LandmarkPairs
    points : array_like (p, 3)
        Source-space points.
    smoothing : float
        Weight decay of the RBF (Eq. 8.3) in units of the target diagonal: 0 interpolates every landmark
        exactly; ``inf`` keeps only the similarity.

    Returns
    -------
    warped : ndarray (p, 3)
    similarity : tuple ``(s, R, t)``
    """
    src, dst = np.asarray(landmarks.source, float), np.asarray(landmarks.target, float)
    s, R, t = similarity(src, dst)
    aligned = s * src @ R.T + t
    P = s * np.asarray(points, dtype=np.float64) @ R.T + t
    scale = max(bbox_diagonal(dst), 1e-300)
    if np.isinf(smoothing):
        return P, (s, R, t)
    if layout(aligned) == "spatial" and layout(dst) == "spatial" and src.shape[0] >= 5:
        warp = fit_rbf(aligned / scale, (dst - aligned) / scale, "thin_plate_spline", 1.0, 1,
                       smoothing=smoothing)
    else:
        warp = fit_rbf(aligned / scale, (dst - aligned) / scale, "linear", 1.0, 0, smoothing=smoothing)
    return P + scale * warp(P / scale), (s, R, t)


def _spd_lu(A):
    """LU of a sparse symmetric positive definite matrix, with a fill-reducing symmetric ordering."""
    return splu(sp.csc_matrix(A), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                options={"SymmetricMode": True})


def _laplacian(n, tris):
    """Uniform graph Laplacian ``I − D⁻¹A`` (n, n), zero rows for vertices in no triangle."""
    e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    A = sp.coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n)).tocsr()
    A.data[:] = 1.0
    deg = np.asarray(A.sum(axis=1)).ravel()
    inv = np.where(deg > 0, 1.0 / np.where(deg > 0, deg, 1.0), 0.0)
    return (sp.diags((deg > 0).astype(float)) - sp.diags(inv) @ A).tocsr()


def _match_parts(Y0, s_part, STri, T, t_part, tol, cover=0.3):
    """Target part → the source part whose warped surface is nearest to most of a sample of its vertices
    (one closest-point query against every source triangle); −1 unless at least ``cover`` of the sample lies
    within ``tol`` of that part (a whole head matches a face-only source; an eyeball far behind the lids,
    or teeth deep in the mouth, do not)."""
    faces = np.flatnonzero(s_part[STri[:, 0]] >= 0)
    rng = np.random.default_rng(0)
    sample = []
    for p in np.unique(t_part):
        if p >= 0:
            idx = np.flatnonzero(t_part == p)
            sample.append(idx if idx.size <= 200 else rng.choice(idx, 200, replace=False))
    sample = np.concatenate(sample) if sample else np.zeros(0, dtype=int)
    out = {}
    if sample.size == 0 or faces.size == 0:
        return {int(p): -1 for p in np.unique(t_part) if p >= 0}
    tri, _, _, dist = closest_on_triangles(T[sample], Y0, STri[faces], candidates=8)
    src = s_part[STri[faces[tri], 0]]
    tp = t_part[sample]
    for p in np.unique(tp):
        m = tp == p
        near = m & (dist <= tol)
        if near.sum() < cover * m.sum():
            out[int(p)] = -1
            continue
        out[int(p)] = int(np.argmax(np.bincount(src[near])))
    return out


def register(src_verts: ArrayLike, src_tris: ArrayLike, dst_verts: ArrayLike, dst_tris: ArrayLike,
             landmarks: LandmarkPairs, *, stiffness: tuple = (8.0, 4.0, 2.0, 1.0, 0.5), inner: int = 3,
             iterations: int = 150, landmark_weight: float = 3.0, max_distance: float = 0.05,
             part_tolerance: float = 0.015, tol: float = 1e-4, warp_smoothing: float = 1e-3, anderson: int = 5,
             progress: ProgressFn | None = None) -> Result:
    """Register the source neutral onto the target neutral and build the dense map.

    Parameters
    ----------
    src_verts : array_like (n_s, 3)
    src_tris : array_like of int (f_s, 3)
    dst_verts : array_like (n_t, 3)
    dst_tris : array_like of int (f_t, 3)
    landmarks : LandmarkPairs
        Checked with :func:`check_landmarks` (≥ 5, not degenerate, not all on one side).
    stiffness : tuple of float
        Decreasing smoothness weights ``α`` (dimensionless: coordinates are divided by the target's
        bounding-box diagonal), Amberg et al. 2007's stiffness schedule.  At each level the closest-point
        pairs are re-estimated until the set of accepted pairs (distance, normal and boundary tests) stops
        changing or for ``inner`` steps, then that set is frozen for the rest of the level (only the closest
        points move; the system is factorised once).  With a fixed pair set the iteration is an alternating
        minimisation whose energy decreases monotonically, so a level ends when the largest vertex move is
        below ``tol`` × diagonal or the energy's relative decrease is below ``tol``.  (Re-testing the pairs
        at every step makes vertices near the distance/normal thresholds flip in and out, which moves them by
        a few tenths of a mm forever: the cause of never converging.)
    inner : int
        Steps per level during which the accepted pair set may still change.
    anderson : int
        Depth of the Anderson acceleration of the fixed-pair-set iteration (0: plain iteration).  Closest-point
        iteration converges only linearly (vertices slide along the surface a little at every step); Anderson
        acceleration (as in Zhang et al. 2021, "Fast and robust iterative closest point") extrapolates from the
        last steps and is kept only when it lowers the energy, else the plain step is taken.
    iterations : int
        Iteration cap of each stiffness level; a level that reaches it makes the status NOT_CONVERGED.
    tol : float
        Relative tolerance (largest move / diagonal, or relative energy decrease).
    landmark_weight : float
        ``β``.
    max_distance : float
        Closest-point pairs further apart than this × diagonal are dropped.
    part_tolerance : float
        A target part is matched to a source part whose warped surface is within this × diagonal.
    warp_smoothing : float
        Weight decay of the landmark warp (see :func:`warp_points`).  Landmarks from shared shapes are
        inconsistent by millimetres (artists' shapes of one name peak at different places); interpolating them
        exactly bakes that into the registration, which the ICP then cannot undo tangentially.  Measured on
        the shared heads (mean relative transfer error): exact 0.635 / 0.635, 10⁻³ 0.621 / 0.435 for
        facecap → FBHead / FBHead → facecap.
    progress : callable (fraction) -> None, optional
        :mod:`core.progress` protocol: called with fractions in [0, 1]; raising
        :class:`~core.progress.Cancelled` from it stops the registration (the exception reaches the caller).

    Returns
    -------
    Result
        ``value``: :class:`Correspondence`; ``iterations`` (all levels); status NOT_CONVERGED when a
        stiffness level reached its iteration cap; ``diagnostics``: ``residual_mm``, ``residual_max_mm``,
        ``coverage`` (fraction of source vertices with an accepted pair), ``seconds``, ``unmatched_parts``,
        ``level_iterations`` (steps per level), ``levels_capped`` (the α of levels that hit the cap).
    """
    t0 = time.perf_counter()
    S, ST = check_mesh(src_verts, src_tris, "source")
    T, TT = check_mesh(dst_verts, dst_tris, "target")
    check_landmarks(landmarks, S, T)
    diag = bbox_diagonal(T)
    if not diag > 0:
        raise ShapeSpaceError("the target mesh has zero size", ErrorCode.DEGENERATE)
    mm = mm_per_unit(T)

    Y0, sim = warp_points(landmarks, S, warp_smoothing)
    s_part, _ = triangle_parts(S.shape[0], ST)
    t_part, _ = triangle_parts(T.shape[0], TT)
    part_map = _match_parts(Y0, s_part, ST, T, t_part, part_tolerance * diag)
    if not any(q >= 0 for q in part_map.values()):
        return Result(None, status=Status.FAILED, diagnostics={"part_map": part_map},
                      message="no part of the target lies on the source after the landmark warp: check the landmark "
                              "pairs (left/right swapped, or on the wrong mesh)")
    # target triangles each source part may be pulled onto
    t_face_part = t_part[TT[:, 0]]
    t_bnd = boundary_vertices(T.shape[0], TT)
    _, t_area = face_normals(T, TT)
    t_fn, _ = face_normals(T, TT)
    targets_of = {}
    for p, q in part_map.items():
        if q >= 0:
            targets_of.setdefault(q, []).append(p)
    groups = []
    for q, ps in targets_of.items():
        faces = np.flatnonzero(np.isin(t_face_part, ps) & (t_area > 0))
        verts = np.flatnonzero(s_part == q)
        if faces.size and verts.size:
            groups.append((verts, faces, cKDTree(T[TT[faces]].mean(axis=1) / diag)))
    # landmark rows: the source vertex of each landmark, or the barycentric combination of the source
    # triangle a free surface point lies on
    lm_idx = np.asarray(landmarks.source_index, dtype=np.int64)
    m = lm_idx.size
    cols = np.repeat(lm_idx[:, None], 3, axis=1)
    vals = np.tile([1.0, 0.0, 0.0], (m, 1))
    free = lm_idx < 0
    if free.any():
        ftri, fbary, _, _ = closest_on_triangles(np.asarray(landmarks.source, float)[free], S, ST)
        cols[free] = ST[ftri]
        vals[free] = fbary
    lm_dst = np.asarray(landmarks.target, dtype=np.float64) / diag
    n = S.shape[0]
    L = _laplacian(n, ST)
    LtL = (L.T @ L).tocsc()
    P = sp.csr_matrix((vals.ravel(), (np.repeat(np.arange(m), 3), cols.ravel())), shape=(m, n))
    PtP = (P.T @ P).tocsc()
    eps = 1e-4
    Yn0 = Y0 / diag
    Y = Yn0.copy()
    Tn = T / diag
    lm_rhs = (landmark_weight ** 2) * (P.T @ lm_dst)
    lm_A = (landmark_weight ** 2) * PtP
    cap = max(1, int(iterations))
    n_levels = len(stiffness)
    w = np.zeros(n)
    c = np.zeros((n, 3))

    def pairs(Y, accept):
        """Closest target points ``c`` of every source vertex, and (``accept``) which pairs pass the tests."""
        ok_all = np.zeros(n, dtype=bool)
        cc = Y.copy()
        vn = vertex_normals(Y, ST) if accept else None
        for verts, faces, tree in groups:
            tri, bary, pt, dist = closest_on_triangles(Y[verts], Tn, TT[faces], candidates=6, tree=tree)
            cc[verts] = pt
            if accept:
                f = faces[tri]
                ok = dist <= max_distance
                ok &= np.einsum("ij,ij->i", vn[verts], t_fn[f]) > 0.3
                corner = TT[f, np.argmax(bary, axis=1)]
                ok &= ~t_bnd[corner]
                ok_all[verts[ok]] = True
        return cc, ok_all

    def energy(Y, alpha):
        d = L @ (Y - Yn0)
        r = P @ Y - lm_dst
        return float((alpha * alpha) * np.sum(d * d) + np.sum(w[:, None] * (Y - c) ** 2)
                     + (landmark_weight ** 2) * np.sum(r * r) + eps * np.sum((Y - Yn0) ** 2))

    it, move, rel_change = 0, np.inf, np.inf
    capped = []                                   # levels that hit their iteration cap: (alpha, last move)
    level_iterations = []
    for li, alpha in enumerate(stiffness):
        alpha = float(alpha)
        lu, mask, frozen = None, None, False
        converged = False
        e_prev = np.inf
        hist_G, hist_F = [], []                   # Anderson history: plain iterates G(Y_j), residuals G(Y_j) − Y_j
        plain = None                              # the plain iterate, when Y is an accelerated one
        for k in range(1, cap + 1):
            it += 1
            c_new, ok = pairs(Y, accept=not frozen)
            if not frozen:
                if mask is not None and (np.array_equal(ok, mask) or k > max(1, inner)):
                    frozen = True                 # the pair set is stable (or re-estimated enough): keep it
                    ok = mask
                if mask is None or not np.array_equal(ok, mask):
                    lu = None
                mask = ok
                w[:] = mask.astype(float)
            if lu is not None:
                # the closest-point search is approximate (nearest triangle centroids): keep the previous surface
                # point where the new one is not nearer, so that E(Y_k, c_k) ≤ E(Y_k, c_{k−1})
                nearer = np.sum((c_new - Y) ** 2, axis=1) <= np.sum((c - Y) ** 2, axis=1)
                c_new = np.where(nearer[:, None], c_new, c)
            c[:] = np.where(mask[:, None], c_new, Y)
            # with the pair set frozen the energy E(Y_k, c_k) then decreases monotonically (alternating minimisation)
            e_now = energy(Y, alpha)
            if plain is not None and e_now > e_prev:
                # the accelerated step raised the energy: take the plain step instead and restart the history
                Y, plain = plain, None
                hist_G.clear()
                hist_F.clear()
                c_new, _ = pairs(Y, accept=False)
                nearer = np.sum((c_new - Y) ** 2, axis=1) <= np.sum((c - Y) ** 2, axis=1)
                c[:] = np.where((mask & nearer)[:, None], c_new, c)
                e_now = energy(Y, alpha)
            plain = None
            rel_change = (e_prev - e_now) / max(e_now, 1e-300) if (lu is not None and np.isfinite(e_prev)) else np.inf
            e_prev = e_now
            if lu is None:
                A = (alpha * alpha) * LtL + sp.diags(w + eps) + lm_A
                lu = _spd_lu(A)
            rhs = (alpha * alpha) * (LtL @ Yn0) + w[:, None] * c + eps * Yn0 + lm_rhs
            Y_new = lu.solve(rhs)
            move = float(np.abs(Y_new - Y).max())
            notify(progress, 0.8 * min(1.0, (li + k / cap) / n_levels))
            if frozen and (move < tol or abs(rel_change) < tol):
                Y = Y_new
                converged = True
                break
            Y_next = Y_new
            if frozen and anderson > 0:
                hist_G.append(Y_new.ravel())
                hist_F.append((Y_new - Y).ravel())
                del hist_G[:-(anderson + 1)], hist_F[:-(anderson + 1)]
                if len(hist_F) >= 2:
                    dF = np.diff(np.asarray(hist_F), axis=0)
                    dG = np.diff(np.asarray(hist_G), axis=0)
                    gamma = np.linalg.lstsq(dF.T, hist_F[-1], rcond=None)[0]
                    Y_acc = (Y_new.ravel() - dG.T @ gamma).reshape(Y.shape)
                    if np.all(np.isfinite(Y_acc)):
                        Y_next, plain = Y_acc, Y_new
            Y = Y_next
        level_iterations.append(k)
        if not converged:
            capped.append((alpha, move))
    status = Status.OK if not capped else Status.NOT_CONVERGED
    registered = Y * diag
    # residual: accepted pairs after the last solve
    res = []
    for verts, faces, tree in groups:
        _, _, _, dist = closest_on_triangles(Y[verts], Tn, TT[faces], candidates=6, tree=tree)
        acc = w[verts] > 0
        res.append(dist[acc] * diag)
    res = np.concatenate(res) if res else np.zeros(0)
    residual = float(np.sqrt(np.mean(res ** 2))) * mm if res.size else float("nan")
    # dense map, per matched part
    tri = np.full(T.shape[0], -1, dtype=np.int64)
    bary = np.zeros((T.shape[0], 3))
    dist = np.full(T.shape[0], np.inf)
    face_tri = np.full(TT.shape[0], -1, dtype=np.int64)
    s_face_part = s_part[ST[:, 0]]
    _, s_area = face_normals(registered, ST)
    centroids = T[TT].mean(axis=1)
    matched_src_faces = np.flatnonzero(np.isin(s_face_part, [q for q in part_map.values() if q >= 0]) & (s_area > 0))
    for p in sorted(set(part_map) | {-1}):
        q = part_map.get(p, -1)
        if p >= 0 and q < 0:
            continue
        faces = np.flatnonzero((s_face_part == q) & (s_area > 0)) if p >= 0 else matched_src_faces
        if faces.size == 0:
            continue
        tree = cKDTree(registered[ST[faces]].mean(axis=1))
        vi = np.flatnonzero(t_part == p)
        if vi.size:
            k, b, _, d = closest_on_triangles(T[vi], registered, ST[faces], candidates=8, tree=tree)
            tri[vi], bary[vi], dist[vi] = faces[k], b, d
        fi = np.flatnonzero(t_face_part == p) if p >= 0 else np.zeros(0, dtype=int)
        if fi.size:
            k, _, _, _ = closest_on_triangles(centroids[fi], registered, ST[faces], candidates=8, tree=tree)
            face_tri[fi] = faces[k]
    corr = Correspondence(registered, tri, bary, dist, face_tri, sim, t_part, part_map, residual, mm)
    unmatched = corr.unmatched_parts()
    diagnostics = {"residual_mm": residual, "residual_max_mm": float(res.max() * mm) if res.size else float("nan"),
                   "coverage": float((w > 0).mean()), "seconds": time.perf_counter() - t0,
                   "last_move": move * diag, "unmatched_parts": unmatched, "level_iterations": level_iterations,
                   "levels_capped": [a for a, _ in capped]}
    msg = (f"registered: residual {residual:.2f} mm RMS over {100 * (w > 0).mean():.0f}% of the source"
           + (f"; {len(unmatched)} target part(s) without a counterpart" if unmatched else ""))
    if status == Status.NOT_CONVERGED:
        a, mv = capped[0]
        msg += (f"; stiffness {a:g} stopped at {cap} iterations (the last still moved a vertex "
                f"{mv * diag * mm:.2g} mm)" + (f", {len(capped) - 1} more level(s) too" if len(capped) > 1 else ""))
    notify(progress, 1.0)
    return Result(corr, status=status, message=msg, iterations=it, diagnostics=diagnostics)
