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
from scipy.sparse.linalg import SuperLU, splu
from scipy.spatial import cKDTree

from .. import validate
from ..errors import ErrorCode
from ..progress import ProgressFn, notify
from ..rbf import fit_rbf
from ..result import Result, ShapeSpaceError, Status
from ..surface import TriangleSurface
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

__all__ = ["Correspondence", "Registration", "similarity", "register", "warp_points"]


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
             level_tol: float = 1e-3, level_inner: int = 1, progress: ProgressFn | None = None) -> Result:
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
        Relative tolerance (largest move / diagonal, or relative energy decrease) of the last stiffness level.
    level_tol, level_inner : float, int
        ``tol`` and ``inner`` of the stiffer levels before the last.  Those only carry the surface towards the
        last level's start, which then converges to ``tol`` with ``inner`` re-estimations of its pair set, so
        converging them tightly buys nothing: on the shared heads (ICT FaceKit as the source) ``1e-3`` and one
        re-estimation cut the ICP steps from 135–240 to 50–70 and the factorisations from 15 to 7, with the
        transfers' relative error within ±0.02 of the tight schedule's (``python tools/bench.py transfer``).
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
        ``level_iterations`` (steps per level), ``levels_capped`` (the α of levels that hit the cap),
        ``factorisations``, ``solved_vertices`` (the source vertices in the system: those of the parts that can
        have a pair or hold a landmark; the others keep the warp).
    """
    return Registration(src_verts, src_tris, dst_verts, dst_tris, landmarks, stiffness=stiffness, inner=inner,
                        iterations=iterations, landmark_weight=landmark_weight, max_distance=max_distance,
                        part_tolerance=part_tolerance, tol=tol, warp_smoothing=warp_smoothing, anderson=anderson,
                        level_tol=level_tol, level_inner=level_inner, progress=progress).run()


class Registration:
    """One run of :func:`register`, one method per step of its pipeline (the module docstring's 1–5).

    The constructor checks the input (the parameters are :func:`register`'s); :meth:`run` does the rest and
    returns the :class:`Result`.  Coordinates inside are divided by the target's bounding-box diagonal.
    """

    def __init__(self, src_verts: ArrayLike, src_tris: ArrayLike, dst_verts: ArrayLike, dst_tris: ArrayLike,
                 landmarks: LandmarkPairs, *, stiffness: tuple, inner: int, iterations: int, landmark_weight: float,
                 max_distance: float, part_tolerance: float, tol: float, warp_smoothing: float, anderson: int,
                 level_tol: float, level_inner: int, progress: ProgressFn | None) -> None:
        self.t0 = time.perf_counter()
        self.S, self.ST = check_mesh(src_verts, src_tris, "source")
        self.T, self.TT = check_mesh(dst_verts, dst_tris, "target")
        check_landmarks(landmarks, self.S, self.T)
        self.diag = bbox_diagonal(self.T)
        if not self.diag > 0:
            raise ShapeSpaceError("the target mesh has zero size", ErrorCode.DEGENERATE)
        self.mm = mm_per_unit(self.T)
        self.landmarks, self.stiffness, self.inner, self.iterations = landmarks, stiffness, inner, iterations
        self.landmark_weight, self.max_distance, self.part_tolerance = landmark_weight, max_distance, part_tolerance
        self.tol, self.warp_smoothing, self.anderson, self.progress = tol, warp_smoothing, anderson, progress
        self.level_tol, self.level_inner = level_tol, level_inner

    def run(self) -> Result:
        """Every step in order; a FAILED result when no target part lies on the warped source."""
        self.warp()
        if not any(q >= 0 for q in self.part_map.values()):
            return Result(None, status=Status.FAILED, diagnostics={"part_map": self.part_map},
                          message="no part of the target lies on the source after the landmark warp: check the "
                                  "landmark pairs (left/right swapped, or on the wrong mesh)")
        self.surface_groups()
        self.system()
        for li, alpha in enumerate(self.stiffness):
            self.level(li, float(alpha))
        registered = self.Y * self.diag
        res = self.residuals()
        residual = float(np.sqrt(np.mean(res ** 2))) * self.mm if res.size else float("nan")
        tri, bary, dist, face_tri = self.dense_map(registered)
        corr = Correspondence(registered, tri, bary, dist, face_tri, self.sim, self.t_part, self.part_map, residual,
                              self.mm)
        return self.result(corr, res)

    # ---- steps 1–3: similarity, warp, parts
    def warp(self) -> None:
        """Similarity + RBF warp of the source (``Y0``); each target part matched to a source part."""
        self.Y0, self.sim = warp_points(self.landmarks, self.S, self.warp_smoothing)
        self.s_part, _ = triangle_parts(self.S.shape[0], self.ST)
        self.t_part, _ = triangle_parts(self.T.shape[0], self.TT)
        self.part_map = _match_parts(self.Y0, self.s_part, self.ST, self.T, self.t_part,
                                     self.part_tolerance * self.diag)

    def surface_groups(self) -> None:
        """The target triangles each source part may be pulled onto: ``groups`` of (source vertices, target
        faces, the :class:`~core.surface.TriangleSurface` of those faces in units of the diagonal); the target's face
        parts, boundary and face normals."""
        T, TT = self.T, self.TT
        self.Tn = T / self.diag
        self.t_face_part = self.t_part[TT[:, 0]]
        self.t_bnd = boundary_vertices(T.shape[0], TT)
        _, t_area = face_normals(T, TT)
        self.t_fn, _ = face_normals(T, TT)
        targets_of = {}
        for p, q in self.part_map.items():
            if q >= 0:
                targets_of.setdefault(q, []).append(p)
        self.groups = []
        for q, ps in targets_of.items():
            faces = np.flatnonzero(np.isin(self.t_face_part, ps) & (t_area > 0))
            verts = np.flatnonzero(self.s_part == q)
            if faces.size and verts.size:
                tree = cKDTree(T[TT[faces]].mean(axis=1) / self.diag)
                self.groups.append((verts, faces, TriangleSurface(self.Tn, TT[faces], tree)))
        self.warm = [{} for _ in self.groups]          # candidate sets re-used between ICP steps
        self.frozen = None                             # per group, once a level's pair set is frozen (see pairs)

    # ---- step 4: non-rigid ICP
    def system(self) -> None:
        """The fixed parts of the sparse system: Laplacian, landmark rows (the source vertex of each landmark,
        or the barycentric combination of the source triangle a free surface point lies on), right-hand sides."""
        S, ST, diag, landmarks = self.S, self.ST, self.diag, self.landmarks
        lm_idx = np.asarray(landmarks.source_index, dtype=np.int64)
        m = lm_idx.size
        cols = np.repeat(lm_idx[:, None], 3, axis=1)
        vals = np.tile([1.0, 0.0, 0.0], (m, 1))
        free = lm_idx < 0
        if free.any():
            ftri, fbary, _, _ = closest_on_triangles(np.asarray(landmarks.source, float)[free], S, ST)
            cols[free] = ST[ftri]
            vals[free] = fbary
        self.lm_dst = np.asarray(landmarks.target, dtype=np.float64) / diag
        n = S.shape[0]
        self.L = _laplacian(n, ST)
        self.LtL = (self.L.T @ self.L).tocsc()
        self.P = sp.csr_matrix((vals.ravel(), (np.repeat(np.arange(m), 3), cols.ravel())), shape=(m, n))
        PtP = (self.P.T @ self.P).tocsc()
        self.eps = 1e-4
        self.Yn0 = self.Y0 / diag
        self.Y = self.Yn0.copy()
        self.lm_rhs = (self.landmark_weight ** 2) * (self.P.T @ self.lm_dst)
        self.lm_A = (self.landmark_weight ** 2) * PtP
        self.LtL_Y0 = self.LtL @ self.Yn0           # constant part of the right-hand side (× α²)
        self.restrict(vals != 0, cols)
        self.cap = max(1, int(self.iterations))
        self.w = np.zeros(n)
        self.c = np.zeros((n, 3))
        self.it, self.move = 0, np.inf
        self.capped = []                          # levels that hit their iteration cap: (alpha, last move)
        self.level_iterations = []
        self.factorisations = 0

    def restrict(self, lm_used: np.ndarray, lm_cols: np.ndarray) -> None:
        """The vertices the system is solved for (``act``) and its fixed parts restricted to them: the source
        parts that can have a pair (a group's vertices) or hold a landmark.  The Laplacian has no edge between
        parts, so every other part's block is ``(α² LᵀL + ε) (Y − Y₀) = 0``: it keeps the warp, ``Y = Y₀``
        (ICT FaceKit as the source: its eyes, teeth, gums, lashes… — 12.7k of 26.7k vertices onto FBHead)."""
        live = np.zeros(self.S.shape[0], dtype=bool)
        for verts, _faces, _surface in self.groups:
            live[verts] = True
        live[lm_cols[lm_used]] = True
        parts = np.unique(self.s_part[live])
        live |= np.isin(self.s_part, parts[parts >= 0])
        a = self.act = np.flatnonzero(live)
        self.LtL_a = self.LtL[a][:, a].tocsc()
        self.lm_A_a = self.lm_A.tocsr()[a][:, a].tocsc()
        self.rhs_a = (self.LtL_Y0[a], self.eps * self.Yn0[a] + self.lm_rhs[a])    # (× α², constant)

    def solve(self, lu: SuperLU, alpha: float) -> np.ndarray:
        """The minimiser of the energy for the current pairs ``w``, ``c`` (``lu``: of the restricted system)."""
        a, w = self.act, self.w
        Y = self.Yn0.copy()
        Y[a] = lu.solve((alpha * alpha) * self.rhs_a[0] + w[a, None] * self.c[a] + self.rhs_a[1])
        return Y

    def factorise(self, alpha: float) -> SuperLU:
        """LU of the restricted system matrix ``α² LᵀL + diag(w + ε) + β² PᵀP``."""
        self.factorisations += 1
        return _spd_lu((alpha * alpha) * self.LtL_a + sp.diags(self.w[self.act] + self.eps) + self.lm_A_a)

    def freeze(self, mask: np.ndarray) -> None:
        """Freeze the pair set ``mask`` (n,): from now on :meth:`pairs` (without ``accept``) queries only the
        accepted source vertices, each group with a candidate state of its own (the others' closest points
        have weight 0; on ICT FaceKit as the source only 20–50 % of the vertices have a pair)."""
        self.frozen = [(verts[mask[verts]], faces, surface, {}) for verts, faces, surface in self.groups]

    def pairs(self, Y: np.ndarray, accept: bool) -> tuple:
        """Closest target points ``c`` of every source vertex, and (``accept``) which pairs pass the tests;
        with the pair set frozen (:meth:`freeze`) and not ``accept``, those of the accepted vertices only (the
        others' ``c`` is ``Y``)."""
        n = self.S.shape[0]
        ok_all = np.zeros(n, dtype=bool)
        cc = Y.copy()
        vn = vertex_normals(Y, self.ST) if accept else None
        groups = self.frozen if self.frozen is not None and not accept else \
            [(verts, faces, surface, warm) for (verts, faces, surface), warm in zip(self.groups, self.warm)]
        for verts, faces, surface, warm in groups:
            if verts.size == 0:
                continue
            tri, bary, pt, dist = surface.closest(Y[verts], candidates=6, warm=warm)
            cc[verts] = pt
            if accept:
                f = faces[tri]
                ok = dist <= self.max_distance
                ok &= np.einsum("ij,ij->i", vn[verts], self.t_fn[f]) > 0.3
                corner = self.TT[f, np.argmax(bary, axis=1)]
                ok &= ~self.t_bnd[corner]
                ok_all[verts[ok]] = True
        return cc, ok_all

    def energy(self, Y: np.ndarray, alpha: float) -> float:
        """The energy of the module docstring at ``Y`` with the current pairs ``w``, ``c``."""
        d = self.L @ (Y - self.Yn0)
        r = self.P @ Y - self.lm_dst
        return float((alpha * alpha) * np.sum(d * d) + np.sum(self.w[:, None] * (Y - self.c) ** 2)
                     + (self.landmark_weight ** 2) * np.sum(r * r) + self.eps * np.sum((Y - self.Yn0) ** 2))

    def level(self, li: int, alpha: float) -> None:
        """One stiffness level ``alpha``: re-estimate the pair set until it is stable (or for ``inner`` steps),
        then freeze it and iterate (Anderson-accelerated) until the move or the energy decrease is below ``tol``."""
        lu, mask, frozen = None, None, False
        self.frozen = None
        converged = False
        e_prev = np.inf
        hist_G, hist_F = [], []                   # Anderson history: plain iterates G(Y_j), residuals G(Y_j) − Y_j
        plain = None                              # the plain iterate, when Y is an accelerated one
        Y, w, c = self.Y, self.w, self.c
        for k in range(1, self.cap + 1):
            self.it += 1
            c_new, ok = self.pairs(Y, accept=not frozen)
            if not frozen:
                inner = self.inner if li == len(self.stiffness) - 1 else self.level_inner
                if mask is not None and (np.array_equal(ok, mask) or k > max(1, inner)):
                    frozen = True                 # the pair set is stable (or re-estimated enough): keep it
                    ok = mask
                    self.freeze(mask)
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
            e_now = self.energy(Y, alpha)
            if plain is not None and e_now > e_prev:
                # the accelerated step raised the energy: take the plain step instead and restart the history
                Y, e_now = self.plain_step(plain, mask, alpha)
                hist_G.clear()
                hist_F.clear()
            plain = None
            rel_change = (e_prev - e_now) / max(e_now, 1e-300) if (lu is not None and np.isfinite(e_prev)) else np.inf
            e_prev = e_now
            if lu is None:
                lu = self.factorise(alpha)
            Y_new = self.solve(lu, alpha)
            self.move = float(np.abs(Y_new - Y).max())
            notify(self.progress, 0.8 * min(1.0, (li + k / self.cap) / len(self.stiffness)))
            tol = self.tol if li == len(self.stiffness) - 1 else self.level_tol
            if frozen and (self.move < tol or abs(rel_change) < tol):
                Y = Y_new
                converged = True
                break
            Y_next = Y_new
            if frozen and self.anderson > 0:
                Y_acc = self.accelerate(hist_G, hist_F, Y_new, Y)
                if Y_acc is not None:
                    Y_next, plain = Y_acc, Y_new
            Y = Y_next
        self.Y = Y
        self.level_iterations.append(k)
        if not converged:
            self.capped.append((alpha, self.move))

    def plain_step(self, plain: np.ndarray, mask: np.ndarray, alpha: float) -> tuple:
        """Back to the plain iterate ``plain`` (the accelerated one raised the energy): its closest points
        where nearer, and its energy; returns ``(Y, energy)``."""
        c = self.c
        c_new, _ = self.pairs(plain, accept=False)
        nearer = np.sum((c_new - plain) ** 2, axis=1) <= np.sum((c - plain) ** 2, axis=1)
        c[:] = np.where((mask & nearer)[:, None], c_new, c)
        return plain, self.energy(plain, alpha)

    def accelerate(self, hist_G: list, hist_F: list, Y_new: np.ndarray, Y: np.ndarray) -> np.ndarray | None:
        """Anderson extrapolation from the last ``anderson`` + 1 steps (the histories are updated in place);
        None while the history is too short or when it is not finite."""
        hist_G.append(Y_new.ravel())
        hist_F.append((Y_new - Y).ravel())
        del hist_G[:-(self.anderson + 1)], hist_F[:-(self.anderson + 1)]
        if len(hist_F) < 2:
            return None
        dF = np.diff(np.asarray(hist_F), axis=0)
        dG = np.diff(np.asarray(hist_G), axis=0)
        gamma = np.linalg.lstsq(dF.T, hist_F[-1], rcond=None)[0]
        Y_acc = (Y_new.ravel() - dG.T @ gamma).reshape(Y.shape)
        return Y_acc if np.all(np.isfinite(Y_acc)) else None

    def residuals(self) -> np.ndarray:
        """Registered-source → target-surface distances (target units) of the accepted pairs after the last solve."""
        res = []
        for verts, _faces, surface in self.groups:
            acc = verts[self.w[verts] > 0]
            if acc.size:
                _, _, _, dist = surface.closest(self.Y[acc], candidates=6)
                res.append(dist * self.diag)
        return np.concatenate(res) if res else np.zeros(0)

    # ---- step 5: the dense map
    def dense_map(self, registered: np.ndarray) -> tuple:
        """Per matched part: each target vertex's and each target triangle centroid's closest point on the
        registered source surface; returns ``(tri, bary, distance, face_tri)``."""
        T, TT, ST, part_map = self.T, self.TT, self.ST, self.part_map
        tri = np.full(T.shape[0], -1, dtype=np.int64)
        bary = np.zeros((T.shape[0], 3))
        dist = np.full(T.shape[0], np.inf)
        face_tri = np.full(TT.shape[0], -1, dtype=np.int64)
        s_face_part = self.s_part[ST[:, 0]]
        _, s_area = face_normals(registered, ST)
        centroids = T[TT].mean(axis=1)
        matched_src_faces = np.flatnonzero(np.isin(s_face_part, [q for q in part_map.values() if q >= 0])
                                           & (s_area > 0))
        surfaces = {}                 # one query per source surface: the target parts matched to one source part
        for p in sorted(set(part_map) | {-1}):
            q = part_map.get(p, -1)
            if p >= 0 and q < 0:
                continue
            faces = np.flatnonzero((s_face_part == q) & (s_area > 0)) if p >= 0 else matched_src_faces
            if faces.size:
                surfaces.setdefault(faces.tobytes(), (faces, []))[1].append(p)
        for faces, parts in surfaces.values():
            vi = np.flatnonzero(np.isin(self.t_part, parts))
            fi = np.flatnonzero(np.isin(self.t_face_part, [p for p in parts if p >= 0]))
            if vi.size + fi.size == 0:
                continue
            k, b, _, d = TriangleSurface(registered, ST[faces]).closest(np.vstack([T[vi], centroids[fi]]),
                                                                        candidates=8)
            tri[vi], bary[vi], dist[vi] = faces[k[:vi.size]], b[:vi.size], d[:vi.size]
            face_tri[fi] = faces[k[vi.size:]]
        return tri, bary, dist, face_tri

    def result(self, corr: Correspondence, res: np.ndarray) -> Result:
        """The :class:`Result` of :func:`register` (status, message and diagnostics)."""
        capped, diag, mm, w = self.capped, self.diag, self.mm, self.w
        status = Status.OK if not capped else Status.NOT_CONVERGED
        residual = corr.residual_mm
        unmatched = corr.unmatched_parts()
        diagnostics = {"residual_mm": residual,
                       "residual_max_mm": float(res.max() * mm) if res.size else float("nan"),
                       "coverage": float((w > 0).mean()), "seconds": time.perf_counter() - self.t0,
                       "last_move": self.move * diag, "unmatched_parts": unmatched,
                       "level_iterations": self.level_iterations, "levels_capped": [a for a, _ in capped],
                       "factorisations": self.factorisations, "solved_vertices": int(self.act.size)}
        msg = (f"registered: residual {residual:.2f} mm RMS over {100 * (w > 0).mean():.0f}% of the source"
               + (f"; {len(unmatched)} target part(s) without a counterpart" if unmatched else ""))
        if status == Status.NOT_CONVERGED:
            a, mv = capped[0]
            msg += (f"; stiffness {a:g} stopped at {self.cap} iterations (the last still moved a vertex "
                    f"{mv * diag * mm:.2g} mm)" + (f", {len(capped) - 1} more level(s) too" if len(capped) > 1
                                                   else ""))
        notify(self.progress, 1.0)
        return Result(corr, status=status, message=msg, iterations=self.it, diagnostics=diagnostics)
