"""Whole-face, delta and PCA forms of a blendshape rig, and diagnostics of its targets.

Thesis ch. 3 (J.P. Lewis, "Learning from the Artist", 2016): 3.7.3 whole-face
``Σ_k c_k b_k`` versus delta ``b0 + B w`` form and sum-to-one ("convex")
weights; 3.4.6 / 3.7.5 affine maps between blendshape weights and PCA
coefficients; 3.7.8 how many PCA components an animation needs; 3.7.1 / 3.7.6
and Fig. 3.12 coherence of the targets; Figs 3.14 / 3.15 sparsity of blendshape
weights versus PCA coefficients.  Vectors over all vertices have length ``3p``,
ordered x0, y0, z0, x1, ... (as :attr:`BlendshapeModel.delta_matrix`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..blendshape import BlendshapeModel
from ..result import Issue, Result, ShapeSpaceError

__all__ = [
    "PCABasis", "to_whole_face", "from_whole_face", "whole_face_weights", "delta_weights",
    "project_convex", "fit_pca", "pca_from_model", "animation_pca", "blendshape_to_pca_maps", "pca_to_blendshape_maps",
    "compression_report", "coherence_matrix", "mutual_coherence", "similar_pairs", "empty_targets",
    "coherence_image", "sparsity_comparison",
]

_EPS = np.finfo(np.float64).eps
_REL_TOL = 1e-7          # the "moves no vertex" threshold of diagnose_model
_CHUNK = 1 << 22         # elements of one temporary frames × coordinates block


def _check_model(model, need_targets=True):
    if not isinstance(model, BlendshapeModel):
        raise ShapeSpaceError(f"model must be a BlendshapeModel, got {type(model).__name__}", "type")
    if need_targets and (model.n_targets == 0 or model.n_vertices == 0):
        raise ShapeSpaceError(f"model is an empty rig ({model.n_targets} targets, "
                              f"{model.n_vertices} vertices)", "empty")


def _array(x, name, ndims, last=None, shape=""):
    """float64 array with ``ndim`` in ``ndims`` (and last dimension ``last``), finite."""
    arr = np.asarray(x, dtype=np.float64)
    if arr.ndim not in ndims or (last is not None and arr.shape[-1] != last):
        raise ShapeSpaceError(f"{name} must have shape {shape}, got {arr.shape}", "shape")
    if not np.all(np.isfinite(arr)):
        raise ShapeSpaceError(f"{name} contains NaN or infinite values", "non_finite")
    return arr


def _positive(x, name):
    if x is None or not np.isfinite(x) or x <= 0:
        raise ShapeSpaceError(f"{name} must be a positive number, got {x}", "range")
    return float(x)


def _fix_signs(U, *others):
    """Make each column's largest-magnitude entry positive (deterministic PCA signs)."""
    if U.shape[1] == 0:
        return (U,) + others
    sgn = np.sign(U[np.abs(U).argmax(axis=0), np.arange(U.shape[1])])
    sgn[sgn == 0] = 1.0
    return (U * sgn,) + tuple(o * sgn for o in others)


# ------------------------------------------------------------- whole-face form
def to_whole_face(model):
    """Whole-face targets ``b_k = b0 + d_k`` (n, p, 3) and the neutral (p, 3) (thesis 3.7.3).

    Primary targets only: in-betweens and combinations are correctives, not faces.
    """
    _check_model(model, need_targets=False)
    return model.neutral + model.deltas, model.neutral.copy()


def from_whole_face(neutral, targets, names, slider_min=None, slider_max=None, reference_name="Basis"):
    """Delta-form :class:`BlendshapeModel` (``d_k = b_k − b0``) from whole-face targets (thesis 3.7.3).

    Parameters
    ----------
    neutral : array_like, shape (p, 3)
    targets : array_like, shape (n, p, 3)
    names : list of str, length n
    slider_min, slider_max : array_like, shape (n,), optional
    """
    b0 = _array(neutral, "neutral", (2,), 3, "(p, 3)")
    bk = _array(targets, "targets", (3,), None, f"(n, {b0.shape[0]}, 3)")
    if bk.shape[1:] != b0.shape:
        raise ShapeSpaceError(f"targets must have shape (n, {b0.shape[0]}, 3), got {bk.shape}", "shape")
    return BlendshapeModel(b0, bk - b0, names, slider_min=slider_min, slider_max=slider_max,
                           reference_name=reference_name)


def whole_face_weights(w):
    """Sum-to-one whole-face weights ``[1 − Σw, w]``, shape (n + 1,) or (f, n + 1) (thesis 3.7.3).

    ``b0 + B w = (1 − Σw) b0 + Σ_k w_k b_k`` for delta weights ``w`` (n,) or
    (f, n); entry 0 weights the neutral.
    """
    arr = _array(w, "w", (1, 2), None, "(n,) or (f, n)")
    return np.concatenate([1.0 - arr.sum(axis=-1, keepdims=True), arr], axis=-1)


def delta_weights(c):
    """Delta weights and neutral scale of any whole-face weights (inverse of :func:`whole_face_weights`).

    ``Σ_{k≥0} c_k b_k = (Σc) b0 + Σ_{k≥1} c_k d_k``: unless ``Σc = 1`` the
    combination scales the neutral itself (the head grows or shrinks about the
    origin), which is why whole-face rigs need sum-to-one weights.

    Parameters
    ----------
    c : array_like, shape (n + 1,) or (f, n + 1)
        Entry 0 weights the neutral ``b0``; convex or not.

    Returns
    -------
    w : ndarray, shape (n,) or (f, n)
        ``c_1 … c_n``.
    scale : float or ndarray, shape (f,)
        ``Σc``: the face is ``scale · b0 + B w``.
    """
    arr = _array(c, "c", (1, 2), None, "(n + 1,) or (f, n + 1)")
    if arr.shape[-1] == 0:
        raise ShapeSpaceError(f"c must have shape (n + 1,) or (f, n + 1) with n ≥ 0, got {arr.shape}", "shape")
    scale = arr.sum(axis=-1)
    return arr[..., 1:].copy(), (float(scale) if arr.ndim == 1 else scale)


def project_convex(w, lo=0.0, hi=1.0):
    """Euclidean projection of slider vectors onto ``{lo ≤ x ≤ hi, Σx ≤ 1}`` (thesis 3.7.3).

    The convex slider mode: the neutral's whole-face weight ``1 − Σx`` stays
    ≥ 0.  KKT: ``x = clip(w − λ, lo, hi)``, ``λ ≥ 0``, ``λ (Σx − 1) = 0``.
    ``Σ clip(w − λ)`` is continuous and non-increasing, so ``λ`` is bracketed
    by bisection (all frames at once) and then made exact by solving
    ``Σx = 1`` on the free set the bracket identifies.

    Parameters
    ----------
    w : array_like, shape (n,) or (f, n)
    lo, hi : float or array_like, shape (n,)
        Finite lower bounds with ``Σ lo ≤ 1``; upper bounds may be ``inf``.
        Returns an array shaped like ``w``.
    """
    arr = _array(w, "w", (1, 2), None, "(n,) or (f, n)")
    n = arr.shape[-1]
    lo = np.broadcast_to(np.asarray(lo, dtype=np.float64), (n,))
    hi = np.broadcast_to(np.asarray(hi, dtype=np.float64), (n,))
    if not np.all(np.isfinite(lo)) or np.any(np.isnan(hi)) or np.any(lo > hi):
        raise ShapeSpaceError("lo must be finite and lo ≤ hi for every slider", "range")
    if lo.sum() > 1.0 + 1e-12 * max(1.0, np.abs(lo).sum()):
        raise ShapeSpaceError(f"lo sums to {lo.sum():g} > 1: the convex slider set is empty", "infeasible")
    x = np.atleast_2d(arr)
    out = np.clip(x, lo, hi)
    rows = np.flatnonzero(out.sum(axis=1) > 1.0)
    if rows.size:
        v = x[rows]
        a, b = np.zeros(rows.size), (v - lo).max(axis=1)    # Σ clip(v − a) > 1 ≥ Σ clip(v − b)
        for _ in range(200):
            mid = 0.5 * (a + b)
            over = np.clip(v - mid[:, None], lo, hi).sum(axis=1) > 1.0
            a, b = np.where(over, mid, a), np.where(over, b, mid)
            if np.all(b - a <= 4 * _EPS * b):
                break
        y = v - b[:, None]
        free = (y > lo) & (y < hi)
        fixed = np.where(free, 0.0, np.where(y >= hi, hi, lo)).sum(axis=1)
        nf = free.sum(axis=1)
        lam = np.where(nf > 0, ((v * free).sum(axis=1) + fixed - 1.0) / np.maximum(nf, 1), b)
        exact, rough = np.clip(v - np.maximum(lam, 0.0)[:, None], lo, hi), np.clip(y, lo, hi)
        better = np.abs(exact.sum(axis=1) - 1.0) <= np.abs(rough.sum(axis=1) - 1.0)
        out[rows] = np.where(better[:, None], exact, rough)
    return out.reshape(arr.shape)


# ------------------------------------------------------------------------ PCA
@dataclass
class PCABasis:
    """A PCA model of the face, ``x ≈ mean + U c`` (thesis 3.4.6).

    Attributes
    ----------
    mean : ndarray, shape (3p,)
    components : ndarray, shape (3p, m)
        ``U``, orthonormal columns.
    variances : ndarray, shape (m,)
        Variance along each component (:func:`pca_from_model`: squared singular values of ``B``).
    """

    mean: np.ndarray
    components: np.ndarray
    variances: np.ndarray

    def __post_init__(self):
        self.mean = np.asarray(self.mean, dtype=np.float64).ravel()
        self.components = np.asarray(self.components, dtype=np.float64)
        self.variances = np.asarray(self.variances, dtype=np.float64)
        d, shape = self.mean.size, self.components.shape
        if len(shape) != 2 or shape[0] != d:
            raise ShapeSpaceError(f"components must have shape ({d}, m), got {shape}", "shape")
        if self.variances.shape != (shape[1],):
            raise ShapeSpaceError(f"variances must have shape ({shape[1]},), got {self.variances.shape}",
                                  "shape")
        if not np.allclose(self.components.T @ self.components, np.eye(shape[1]), atol=1e-8):
            raise ShapeSpaceError("components must have orthonormal columns", "not_orthonormal")

    @property
    def n_components(self) -> int:
        return self.components.shape[1]

    def project(self, frames):
        """Coefficients ``Uᵀ(x − mean)``, shape (f, m), of frames (f, 3p) or (f, p, 3)."""
        return (np.asarray(frames, dtype=np.float64).reshape(-1, self.mean.size) - self.mean) @ self.components

    def reconstruct(self, coeffs):
        """Frames ``mean + U c``, shape (f, 3p), of coefficients (f, m)."""
        return self.mean + np.atleast_2d(coeffs) @ self.components.T


def fit_pca(frames, n_components=None, tol=None):
    """PCA of example frames by a thin SVD of the centred data (thesis 3.4.6).

    Parameters
    ----------
    frames : array_like, shape (f, 3p) or (f, p, 3)
        ``f ≥ 2``.
    n_components : int, optional
        Keep at most this many components.
    tol : float, optional
        Drop components whose singular value is ≤ ``tol`` × the largest
        (default ``max(f, 3p) · eps``: numerically zero directions).  Returns a :class:`PCABasis`.
    """
    x = _array(frames, "frames", (2, 3), None, "(f, 3p) or (f, p, 3)")
    if x.ndim == 3 and x.shape[2] == 3:
        x = x.reshape(x.shape[0], -1)
    if x.ndim != 2 or x.shape[1] % 3 or x.shape[1] == 0:
        raise ShapeSpaceError(f"frames must have shape (f, 3p) or (f, p, 3), got {x.shape}", "shape")
    if x.shape[0] < 2:
        raise ShapeSpaceError(f"frames must hold at least 2 frames for PCA, got {x.shape[0]}", "too_few")
    rel = max(x.shape) * _EPS if tol is None else _positive(tol, "tol")
    if n_components is not None and (int(n_components) != n_components or n_components < 1):
        raise ShapeSpaceError(f"n_components must be a positive integer, got {n_components}", "range")
    mean = x.mean(axis=0)
    _, s, vt = np.linalg.svd(x - mean, full_matrices=False)
    m = int(np.sum(s > rel * s[0])) if s[0] > 0 else 0
    m = m if n_components is None else min(m, int(n_components))
    return PCABasis(mean, _fix_signs(vt[:m].T)[0], s[:m] ** 2 / (x.shape[0] - 1))


def pca_from_model(model, rel_tol=_REL_TOL):
    """Exact :class:`PCABasis` of the rig itself: ``mean = b0``, ``U`` an orthonormal basis of range(``B``).

    Left singular vectors of ``B`` with singular value > ``rel_tol × model.scale``
    (empty and duplicated targets add none); ``variances`` are their squares.
    Both maps of thesis 3.7.5 round-trip exactly when ``B`` has full column rank.
    """
    _check_model(model)
    U, s, _ = np.linalg.svd(model.delta_matrix, full_matrices=False)
    r = int(np.sum(s > max(_positive(rel_tol, "rel_tol") * (model.scale or 1.0), s[0] * U.shape[0] * _EPS)))
    return PCABasis(model.neutral.ravel(), _fix_signs(U[:, :r])[0], s[:r] ** 2)


def _check_basis(model, basis):
    _check_model(model)
    if not isinstance(basis, PCABasis):
        raise ShapeSpaceError(f"basis must be a PCABasis, got {type(basis).__name__}", "type")
    if basis.mean.size != 3 * model.n_vertices:
        raise ShapeSpaceError(f"basis.mean must have shape ({3 * model.n_vertices},) to match the rig, "
                              f"got ({basis.mean.size},)", "shape")


def blendshape_to_pca_maps(model, basis):
    """Affine map ``c = A w + a`` from weights to PCA coefficients (thesis 3.4.6, 3.7.5).

    Returns ``A`` (m, n) and ``a`` (m,); ``c`` is the projection ``Uᵀ(b0 + B w − mean)``
    exactly (primary targets: in-betweens and combinations are not linear in ``w``).
    """
    _check_basis(model, basis)
    U = basis.components
    return U.T @ model.delta_matrix, U.T @ (model.neutral.ravel() - basis.mean)


def pca_to_blendshape_maps(model, basis):
    """Least-squares affine map ``w = P c + q`` from PCA coefficients to weights (thesis 3.7.5).

    Returns ``P`` (n, m) and ``q`` (n,): ``w = B⁺(mean + U c − b0)``, ``B⁺`` applied by
    one SVD-based least-squares solve (not the normal equations), minimum-norm when
    ``B`` is rank deficient.  Inverts :func:`blendshape_to_pca_maps` exactly when
    ``span(U) ⊇ span(B)`` and ``B`` has full column rank.
    """
    _check_basis(model, basis)
    rhs = np.column_stack([basis.components, basis.mean - model.neutral.ravel()])
    sol = np.linalg.lstsq(model.delta_matrix, rhs, rcond=None)[0]
    return sol[:, :-1], sol[:, -1]


# ---------------------------------------------------------------- compression
def _animation(model, weights):
    """Validated sliders (f, n) and the frames' linear form ``b0 + B_e w_e`` (driven keys as columns)."""
    _check_model(model)
    raw = _array(weights, "weights", (2,), model.n_targets, f"(f, {model.n_targets})")
    if raw.shape[0] < 2:
        raise ShapeSpaceError(f"weights must hold at least 2 frames for PCA, got {raw.shape[0]}", "too_few")
    W, B = model.effective_weights(raw), model.delta_matrix
    if not model.is_linear:
        W = np.hstack([W, model.driven_values(raw)])
        B = np.hstack([B, model.driven_deltas().reshape(-1, B.shape[0]).T])
    return raw, W, B


def _animation_pca(W, B, neutral):
    """PCA of frames ``b0 + B w_t`` without forming them: centred frames are ``(W − μ) Rᵀ Qᵀ``.

    With ``B = Q R`` (thin QR) the SVD of the small ``(W − μ) Rᵀ = Uy S Vᵀ``
    gives scores ``Uy S`` (f, r) and components ``Q V`` (3p, r).  Also returns
    the singular values of ``B`` (those of ``R``).
    """
    mu = W.mean(axis=0)
    Q, R = np.linalg.qr(B)
    Uy, s, vt = np.linalg.svd((W - mu) @ R.T, full_matrices=False)
    r = int(np.sum(s > s[0] * max(W.shape[0], B.shape[0]) * _EPS)) if s[0] > 0 else 0
    comps, scores = _fix_signs(Q @ vt[:r].T, Uy[:, :r] * s[:r])
    basis = PCABasis(neutral.ravel() + B @ mu, comps, s[:r] ** 2 / (W.shape[0] - 1))
    return basis, scores, np.linalg.svd(R, compute_uv=False)


def animation_pca(model, weights):
    """PCA of an animation's frames ``b0 + B w_t`` (f frames), without forming the f × 3p frame matrix.

    Returns a :class:`PCABasis` whose components are ordered by decreasing variance (all nonzero ones).
    """
    _, W, B = _animation(model, weights)
    return _animation_pca(W, B, model.neutral)[0]


def _block_max(S, Uv, frames, verts):
    """Exact max over ``frames × verts`` of ‖Σ_k S[t, k] Uv[i, :, k]‖ (chunked over vertices)."""
    best, step, St = 0.0, max(1, _CHUNK // (3 * frames.size)), S[frames]
    for j in range(0, verts.size, step):
        e = (St @ Uv[verts[j:j + step]].reshape(-1, Uv.shape[2]).T).reshape(frames.size, -1, 3)
        best = max(best, float(np.sqrt(np.einsum("tic,tic->ti", e, e).max())))
    return best


def _clusters(X, G):
    """Farthest-point centres (rows of ``X``, chosen on a fixed subsample) and nearest-centre labels."""
    sub = np.random.default_rng(0).permutation(X.shape[0])[:max(4 * G, 2048)]
    Y = X[sub]
    centres = [int(np.argmax((Y ** 2).sum(axis=1)))]
    d2 = ((Y - Y[centres[0]]) ** 2).sum(axis=1)
    while len(centres) < G and d2.max() > 0:
        centres.append(int(np.argmax(d2)))
        d2 = np.minimum(d2, ((Y - Y[centres[-1]]) ** 2).sum(axis=1))
    C, centres = Y[centres], sub[centres]
    label = np.argmin((C ** 2).sum(axis=1) - 2 * X @ C.T, axis=1)
    label[centres] = np.arange(centres.size)     # no cluster empty, whatever the rounding
    return centres, label


def _max_vertex_errors(U, S, m_max, groups=256):
    """``errors[m]``, m = 0 … m_max: max 3-D vertex error of the rank-``m`` reconstruction.

    The residual of frame ``t`` at vertex ``i`` is ``U_i a_t`` (``U_i`` = rows of vertex
    ``i`` in ``U[:, m:]``, ``a_t = S[t, m:]``).  Vertices are clustered by their rows of
    ``U`` around centre vertices ``c``, and ``‖U_i a_t‖ ≤ ‖U_c a_t‖ + ‖U_i − U_c‖₂ ‖a_t‖``
    (spectral norms from 3×3 suffix Grams, updated one component at a time).  After
    the exact errors of the centres, only frames and vertices whose bound beats the
    best exact error are evaluated: exact, and on smooth rigs a fraction of all pairs.
    """
    (f, r), p = S.shape, U.shape[0] // 3
    if r == 0:
        return np.zeros(m_max + 1)
    Uv = U.reshape(p, 3, r)
    centres, label = _clusters(U.reshape(p, -1), min(groups, p))
    Dv = Uv - Uv[centres[label]]
    order = np.argsort(label, kind="stable")
    starts = np.searchsorted(label[order], np.arange(centres.size))
    members = np.split(order, starts[1:])
    gram, fn2, errors = np.zeros((p, 3, 3)), np.zeros(f), np.zeros(m_max + 1)
    for m in range(r - 1, -1, -1):
        gram += Dv[:, :, m, None] * Dv[:, None, :, m]
        fn2 += S[:, m] ** 2
        if m > m_max:
            continue
        dv = np.sqrt(np.maximum(np.linalg.eigvalsh(gram)[:, -1], 0.0)) * (1 + 1e-9)
        fb = np.sqrt(fn2) * (1 + 1e-9)
        Sm, Um = S[:, m:], Uv[:, :, m:]
        ec = (Sm @ Um[centres].reshape(-1, r - m).T).reshape(f, -1, 3)
        ec = np.sqrt(np.einsum("tgc,tgc->tg", ec, ec))
        best, dmax = float(ec.max()), np.maximum.reduceat(dv[order], starts)
        cb = ec.max(axis=0) + dmax * fb.max()
        for g in np.argsort(-cb):
            if cb[g] <= best:
                break
            frames = np.flatnonzero(ec[:, g] + dmax[g] * fb > best)
            verts = members[g][ec[frames, g].max() + dv[members[g]] * fb[frames].max() > best] \
                if frames.size else frames
            if verts.size:
                best = max(best, _block_max(Sm, Um, frames, verts))
        errors[m] = best
    return errors


def compression_report(model, weights, tol, max_components=None):
    """How many PCA components reproduce an animation to ``tol`` (thesis 3.7.8).

    PCA of the frames :meth:`BlendshapeModel.evaluate` gives (correctives
    included); the error of a rank-``m`` reconstruction is the largest Euclidean
    3-D vertex error over all frames and vertices.

    Parameters
    ----------
    model : BlendshapeModel
    weights : array_like, shape (f, n)
        Slider values per frame, ``f ≥ 2``.
    tol : float
        Acceptable max vertex error (object units), > 0.
    max_components : int, optional
        Largest ``m`` tried (default: the animation's rank).

    Returns
    -------
    Result
        ``value``: smallest ``m`` with error ≤ ``tol`` (``None`` and status −1 if
        no ``m ≤ max_components`` reaches it).  ``diagnostics``: ``errors`` (m = 0 …
        M), ``n_targets``, ``n_frames``, ``compression_ratio`` (n / m),
        ``animation_rank``, ``rig_rank`` (components reproducing the rig's whole
        target span), ``singular_values``, ``tol``.
    """
    raw, W, B = _animation(model, weights)
    tol = _positive(tol, "tol")
    if max_components is not None and (int(max_components) != max_components or max_components < 0):
        raise ShapeSpaceError(f"max_components must be a non-negative integer, got {max_components}", "range")
    basis, scores, sv_rig = _animation_pca(W, B, model.neutral)
    r = basis.n_components
    M = r if max_components is None else min(r, int(max_components))
    errors = _max_vertex_errors(basis.components, scores, M)
    ok = np.flatnonzero(errors <= tol)
    m = int(ok[0]) if ok.size else None
    cut = max(_REL_TOL * (model.scale or 1.0), sv_rig[0] * B.shape[0] * _EPS)
    diag = {"errors": errors, "n_targets": model.n_targets, "n_frames": raw.shape[0],
            "compression_ratio": None if m is None else (model.n_targets / m if m else np.inf),
            "animation_rank": r, "rig_rank": int(np.sum(sv_rig > cut)), "tol": tol,
            "singular_values": np.sqrt(basis.variances * (raw.shape[0] - 1))}
    if m is None:
        msg = f"{M} components leave a max vertex error of {errors[-1]:.3g} > tol {tol:.3g}"
        return Result(value=None, status=-1, message=msg, diagnostics=diag, issues=[Issue("error", "tolerance_not_met", msg)])
    return Result(value=m, status=0, message=f"{m} of {model.n_targets} components reach max vertex error "
                        f"{errors[m]:.3g} ≤ {tol:.3g}", diagnostics=diag)
# ---------------------------------------------------------------- diagnostics
def _empty_mask(model, rel_tol):
    _check_model(model, need_targets=False)
    limit = _positive(rel_tol, "rel_tol") * (model.scale or 1.0)
    if model.deltas.size == 0:
        return np.zeros(model.n_targets, bool)
    return np.linalg.norm(model.deltas, axis=2).max(axis=1) <= limit


def empty_targets(model, rel_tol=_REL_TOL):
    """Names of targets whose largest vertex displacement is ≤ ``rel_tol`` × the neutral's bbox diagonal."""
    return [model.names[k] for k in np.flatnonzero(_empty_mask(model, rel_tol))]


def coherence_matrix(model, rel_tol=_REL_TOL):
    """Target coherence ``|⟨d_i, d_j⟩| / (‖d_i‖ ‖d_j‖)`` (thesis 3.7.1, 3.7.6, Fig. 3.12).

    Returns
    -------
    ndarray, shape (n, n)
        Symmetric, in [0, 1], unit diagonal; rows, columns and diagonal entries
        of :func:`empty_targets` are 0 (a 0 on the diagonal lists them).
    """
    live = ~_empty_mask(model, rel_tol)
    flat = model.deltas.reshape(model.n_targets, 3 * model.n_vertices)
    unit = np.where(live[:, None], flat, 0.0)
    unit[live] /= np.linalg.norm(flat[live], axis=1)[:, None]
    C = np.minimum(np.abs(unit @ unit.T), 1.0)
    C[np.diag_indices_from(C)] = live
    return C


def mutual_coherence(model, rel_tol=_REL_TOL):
    """Largest off-diagonal coherence of the targets (0 with fewer than two)."""
    C = coherence_matrix(model, rel_tol)
    return float((C - np.diag(np.diag(C))).max()) if C.shape[0] > 1 else 0.0


def similar_pairs(model, threshold=0.95, rel_tol=_REL_TOL):
    """``(name_i, name_j, coherence)`` for ``i < j`` with coherence ≥ ``threshold``, most similar first."""
    if not 0 < threshold <= 1:
        raise ShapeSpaceError(f"threshold must be in (0, 1], got {threshold}", "range")
    C = coherence_matrix(model, rel_tol)
    ii, jj = np.nonzero(np.triu(C >= threshold, k=1))
    return sorted([(model.names[i], model.names[j], float(C[i, j])) for i, j in zip(ii, jj)],
                  key=lambda t: -t[2])


# Samples of a viridis-like ramp (dark purple → blue → green → yellow), RGB 0–255.
_RAMP = np.array([[68, 1, 84], [72, 40, 120], [62, 74, 137], [49, 104, 142], [38, 130, 142],
                  [31, 158, 137], [53, 183, 121], [109, 205, 89], [180, 222, 44], [253, 231, 37]], float)


def coherence_image(C, size=None):
    """Heat map of a coherence matrix as RGBA uint8, shape (n·cell, n·cell, 4).

    0 is dark purple and 1 bright yellow, so the unit diagonal stands out.  Row
    0 of the array is target 0 (top of the picture); Blender images start at
    the bottom row, so a bridge flips it (``[::-1]``) before filling pixels.

    ``C`` (n, n) is clipped to [0, 1] (NaN shows as 0); ``size`` is the approximate
    side in pixels (default 256), ``cell = max(1, size // n)``.
    """
    C = np.asarray(C, dtype=np.float64)
    if C.ndim != 2 or C.shape[0] != C.shape[1] or C.shape[0] == 0:
        raise ShapeSpaceError(f"C must have shape (n, n) with n ≥ 1, got {C.shape}", "shape")
    size = 256 if size is None else size
    if int(size) != size or size < 1:
        raise ShapeSpaceError(f"size must be a positive integer, got {size}", "range")
    cell = max(1, int(size) // C.shape[0])
    t = np.clip(np.nan_to_num(C, nan=0.0), 0.0, 1.0) * (len(_RAMP) - 1)
    k = np.minimum(t.astype(int), len(_RAMP) - 2)
    rgb = _RAMP[k] + (t - k)[..., None] * (_RAMP[k + 1] - _RAMP[k])
    rgba = np.concatenate([np.rint(rgb), np.full(C.shape + (1,), 255.0)], axis=-1).astype(np.uint8)
    return np.repeat(np.repeat(rgba, cell, axis=0), cell, axis=1)


def _hoyer(X):
    """Mean over rows with a nonzero entry of the Hoyer sparsity ``(√k − L1/L2)/(√k − 1)``."""
    k, l2 = X.shape[1], np.sqrt((X ** 2).sum(axis=1))
    live = l2 > 0
    if k < 2 or not live.any():
        return 1.0 if live.any() else np.nan
    return float(np.mean((np.sqrt(k) - np.abs(X[live]).sum(axis=1) / l2[live]) / (np.sqrt(k) - 1)))


def _sparsity(X, energy):
    """Sparsity numbers of coefficients ``X`` (f, k) with per-coefficient energies (f, k)."""
    f, k = X.shape
    A = np.abs(X)
    live = A.max(axis=1) > 0 if k else np.zeros(f, bool)
    out = {"n_coefficients": k, "zero_frames": int(f - live.sum())}
    if not live.any():
        return dict(out, hoyer=np.nan, hoyer_rms=np.nan, small_fraction=np.nan, count_95_energy=np.nan,
                    curve_small_fraction=np.nan)
    rms = np.sqrt((X ** 2).mean(axis=0))
    cum = np.cumsum(-np.sort(-energy[live], axis=1), axis=1)
    return dict(out, hoyer=_hoyer(X), hoyer_rms=_hoyer(X / np.where(rms > 0, rms, 1.0)),
                small_fraction=float((A[live] <= 0.01 * A[live].max(axis=1, keepdims=True)).mean()),
                count_95_energy=float(((cum < 0.95 * cum[:, -1:]).sum(axis=1) + 1).mean()),
                curve_small_fraction=float((A <= 0.01 * A.max(axis=0)).mean()))


def sparsity_comparison(model, weights, basis=None):
    """Sparsity of an animation's blendshape weights versus its PCA coefficients (thesis Figs 3.14, 3.15).

    Blendshape form: effective weights ``w`` (f, n); the energy of target ``k`` is
    its contribution's squared norm ``‖w_k d_k‖²`` (targets are not orthogonal, so
    these need not add up to the frame's).  PCA form: ``c = Uᵀ(x_t − mean)``
    centred over the frames (``basis`` default: PCA of this animation), energy
    ``c_k²`` (``U`` is orthonormal).  Per form, over frames with a nonzero
    coefficient vector: mean Hoyer sparsity ``(√k − L1/L2)/(√k − 1)`` (1 = one
    nonzero, 0 = all equal) of the raw coefficients (``hoyer``) and of each
    coefficient divided by its RMS over the animation (``hoyer_rms``: PCA's raw
    coefficients are ordered by variance, which alone makes them look sparse per
    frame); ``small_fraction``, coefficients at most 1 % of the frame's largest;
    ``count_95_energy``, coefficients holding 95 % of the frame's energy.  And
    ``curve_small_fraction``: samples at most 1 % of their own curve's largest
    over the animation (the per-curve view of the figures).

    Parameters
    ----------
    model : BlendshapeModel
    weights : array_like, shape (f, n)
    basis : PCABasis, optional

    Returns
    -------
    Result
        ``value = {"blendshape": {...}, "pca": {...}}``, each also with
        ``n_coefficients`` and ``zero_frames``.
    """
    raw, W, B = _animation(model, weights)
    basis = _animation_pca(W, B, model.neutral)[0] if basis is None else basis
    _check_basis(model, basis)
    U = basis.components
    c = W @ (U.T @ B).T + U.T @ (model.neutral.ravel() - basis.mean)
    c -= c.mean(axis=0)
    w = W[:, :model.n_targets]
    bs = _sparsity(w, w ** 2 * (model.deltas.reshape(model.n_targets, -1) ** 2).sum(axis=1))
    pc = _sparsity(c, c ** 2)
    msg = (f"blendshape ({model.n_targets} weights) vs PCA ({basis.n_components} coefficients): Hoyer "
           f"{bs['hoyer']:.2f} vs {pc['hoyer']:.2f}, RMS-scaled {bs['hoyer_rms']:.2f} vs {pc['hoyer_rms']:.2f}, "
           f"idle curve samples {bs['curve_small_fraction']:.2f} vs {pc['curve_small_fraction']:.2f}")
    return Result(value={"blendshape": bs, "pca": pc}, status=0, message=msg, diagnostics={"n_frames": raw.shape[0], "n_targets": model.n_targets, "n_components": basis.n_components})
