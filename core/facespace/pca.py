"""PCA form of a face: bases, the affine maps to and from blendshape weights, compression (thesis 3.4.6, 3.7).

J.P. Lewis, *Learning from the Artist*, 2016: 3.4.6 PCA models of the face
``x ≈ mean + U c``; 3.7.5 the affine maps between blendshape weights and PCA
coefficients, ``c = A w + a`` and its least-squares inverse; 3.7.8 how many PCA
components an animation needs to stay within a vertex tolerance.  Vectors over all
vertices have length ``3p``, ordered x0, y0, z0, x1, … (as
:attr:`BlendshapeModel.delta_matrix`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .. import validate
from ..blendshape import BlendshapeModel
from ..errors import ErrorCode
from ..result import Issue, Result, ShapeSpaceError, Status
from ._common import EPS, REL_TOL, check_model, count, shaped

__all__ = ["PCABasis", "PCASliders", "fit_pca", "pca_from_model", "animation_pca", "blendshape_to_pca_maps",
           "pca_to_blendshape_maps", "compression_report", "compressed_animation_pca", "pca_sliders",
           "animation_linear_form", "check_basis"]

_CHUNK = 1 << 22         # elements of one temporary frames × coordinates block


def _fix_signs(U, *others):
    """Make each column's largest-magnitude entry positive (deterministic PCA signs)."""
    if U.shape[1] == 0:
        return (U,) + others
    sgn = np.sign(U[np.abs(U).argmax(axis=0), np.arange(U.shape[1])])
    sgn[sgn == 0] = 1.0
    return (U * sgn,) + tuple(o * sgn for o in others)


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
            raise ShapeSpaceError(f"components must have shape ({d}, m), got {shape}", ErrorCode.SHAPE)
        if self.variances.shape != (shape[1],):
            raise ShapeSpaceError(f"variances must have shape ({shape[1]},), got {self.variances.shape}",
                                  ErrorCode.SHAPE)
        if not np.allclose(self.components.T @ self.components, np.eye(shape[1]), atol=1e-8):
            raise ShapeSpaceError("components must have orthonormal columns", ErrorCode.NOT_ORTHONORMAL)

    @property
    def n_components(self) -> int:
        """``m``, the number of components."""
        return self.components.shape[1]

    def project(self, frames: ArrayLike) -> np.ndarray:
        """Coefficients ``c = Uᵀ(x − mean)``, shape (f, m), of frames ``x`` (f, 3p) or (f, p, 3)."""
        return (np.asarray(frames, dtype=np.float64).reshape(-1, self.mean.size) - self.mean) @ self.components

    def reconstruct(self, coeffs: ArrayLike) -> np.ndarray:
        """Frames ``mean + U c``, shape (f, 3p), of coefficients ``c`` (f, m) or (m,)."""
        return self.mean + np.atleast_2d(coeffs) @ self.components.T

    def truncated(self, m: int) -> PCABasis:
        """The basis of the first ``m`` components (largest variances first), ``0 ≤ m``."""
        m = count(m, "m", 0)
        return PCABasis(self.mean, self.components[:, :m], self.variances[:m])


def fit_pca(frames: ArrayLike, n_components: int | None = None, tol: float | None = None) -> PCABasis:
    """PCA of example frames by a thin SVD of the centred data (thesis 3.4.6).

    Parameters
    ----------
    frames : array_like, shape (f, 3p) or (f, p, 3)
        ``f ≥ 2``.
    n_components : int, optional
        Keep at most this many components.
    tol : float, optional
        Drop components whose singular value is ≤ ``tol`` × the largest (default
        ``max(f, 3p) · eps``: numerically zero directions).

    Returns
    -------
    PCABasis
        ``mean`` (3p,), ``components`` (3p, m), ``variances = s² / (f − 1)`` (m,).
    """
    x = shaped(frames, "frames", "(f, 3p) or (f, p, 3)", ndims=(2, 3))
    if x.ndim == 3 and x.shape[2] == 3:
        x = x.reshape(x.shape[0], -1)
    if x.ndim != 2 or x.shape[1] % 3 or x.shape[1] == 0:
        raise ShapeSpaceError(f"frames must have shape (f, 3p) or (f, p, 3), got {x.shape}", ErrorCode.SHAPE)
    if x.shape[0] < 2:
        raise ShapeSpaceError(f"frames must hold at least 2 frames for PCA, got {x.shape[0]}", ErrorCode.TOO_FEW)
    rel = max(x.shape) * EPS if tol is None else validate.positive(tol, "tol")
    if n_components is not None:
        n_components = count(n_components, "n_components", 1)
    mean = x.mean(axis=0)
    _, s, vt = np.linalg.svd(x - mean, full_matrices=False)
    m = int(np.sum(s > rel * s[0])) if s[0] > 0 else 0
    m = m if n_components is None else min(m, n_components)
    return PCABasis(mean, _fix_signs(vt[:m].T)[0], s[:m] ** 2 / (x.shape[0] - 1))


def pca_from_model(model: BlendshapeModel, rel_tol: float = REL_TOL) -> PCABasis:
    """Exact PCA basis of the rig itself: ``mean = b0``, ``U`` an orthonormal basis of range(``B``) (3.7.5).

    Left singular vectors of ``B`` (3p, n) with singular value > ``rel_tol × model.scale``
    (empty and duplicated targets add none).  Both maps of thesis 3.7.5 round-trip exactly
    when ``B`` has full column rank.

    Parameters
    ----------
    model : BlendshapeModel
    rel_tol : float
        Relative to the neutral's bounding-box diagonal.

    Returns
    -------
    PCABasis
        ``mean`` (3p,), ``components`` (3p, r), ``variances`` the squared singular values (r,).
    """
    check_model(model)
    U, s, _ = np.linalg.svd(model.delta_matrix, full_matrices=False)
    r = int(np.sum(s > max(validate.positive(rel_tol, "rel_tol") * (model.scale or 1.0), s[0] * U.shape[0] * EPS)))
    return PCABasis(model.neutral.ravel(), _fix_signs(U[:, :r])[0], s[:r] ** 2)


def check_basis(model: BlendshapeModel, basis: PCABasis) -> None:
    """Refuse a basis that is not a :class:`PCABasis` over the rig's ``3p`` coordinates."""
    check_model(model)
    if not isinstance(basis, PCABasis):
        raise ShapeSpaceError(f"basis must be a PCABasis, got {type(basis).__name__}", ErrorCode.TYPE)
    if basis.mean.size != 3 * model.n_vertices:
        raise ShapeSpaceError(f"basis.mean must have shape ({3 * model.n_vertices},) to match the rig, "
                              f"got ({basis.mean.size},)", ErrorCode.SHAPE)


def blendshape_to_pca_maps(model: BlendshapeModel, basis: PCABasis) -> tuple[np.ndarray, np.ndarray]:
    """Affine map ``c = A w + a`` from weights to PCA coefficients (thesis 3.4.6, 3.7.5).

    ``c`` is the projection ``Uᵀ(b0 + B w − mean)`` exactly (primary targets: in-betweens
    and combinations are not linear in ``w``).

    Parameters
    ----------
    model : BlendshapeModel
        ``n`` targets.
    basis : PCABasis
        ``m`` components over the rig's vertices.

    Returns
    -------
    A : ndarray, shape (m, n)
        ``Uᵀ B``.
    a : ndarray, shape (m,)
        ``Uᵀ (b0 − mean)``.
    """
    check_basis(model, basis)
    U = basis.components
    return U.T @ model.delta_matrix, U.T @ (model.neutral.ravel() - basis.mean)


def pca_to_blendshape_maps(model: BlendshapeModel, basis: PCABasis) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares affine map ``w = P c + q`` from PCA coefficients to weights (thesis 3.7.5).

    ``w = B⁺(mean + U c − b0)``, ``B⁺`` applied by one SVD-based least-squares solve (not
    the normal equations), minimum-norm when ``B`` is rank deficient.  Inverts
    :func:`blendshape_to_pca_maps` exactly when ``span(U) ⊇ span(B)`` and ``B`` has full
    column rank.

    Parameters
    ----------
    model : BlendshapeModel
        ``n`` targets.
    basis : PCABasis
        ``m`` components over the rig's vertices.

    Returns
    -------
    P : ndarray, shape (n, m)
    q : ndarray, shape (n,)
    """
    check_basis(model, basis)
    rhs = np.column_stack([basis.components, basis.mean - model.neutral.ravel()])
    sol = np.linalg.lstsq(model.delta_matrix, rhs, rcond=None)[0]
    return sol[:, :-1], sol[:, -1]


# ---------------------------------------------------------------- PCA of an animation
def animation_linear_form(model: BlendshapeModel, weights: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validated sliders and the linear form ``b0 + B_e w_e`` of an animation's frames.

    Correctives (in-betweens, combinations) become extra columns of ``B_e`` driven by
    their values, so every frame :meth:`BlendshapeModel.evaluate` gives is reproduced.

    Parameters
    ----------
    model : BlendshapeModel
        ``n`` targets, ``e ≥ n`` effective columns.
    weights : array_like, shape (f, n)
        Slider values per frame, ``f ≥ 2``.

    Returns
    -------
    raw : ndarray, shape (f, n)
        The checked sliders.
    W : ndarray, shape (f, e)
        Effective weights ``w_e``.
    B : ndarray, shape (3p, e)
        ``B_e``.
    """
    check_model(model)
    raw = shaped(weights, "weights", f"(f, {model.n_targets})", ndims=(2,), last=model.n_targets)
    if raw.shape[0] < 2:
        raise ShapeSpaceError(f"weights must hold at least 2 frames for PCA, got {raw.shape[0]}", ErrorCode.TOO_FEW)
    W, B = model.effective_weights(raw), model.delta_matrix
    if not model.is_linear:
        W = np.hstack([W, model.driven_values(raw)])
        B = np.hstack([B, model.driven_deltas().reshape(-1, B.shape[0]).T])
    return raw, W, B


def _animation_pca(W, B, neutral):
    """PCA of frames ``b0 + B w_t`` without forming them: centred frames are ``(W − μ) Rᵀ Qᵀ``.

    With ``B = Q R`` (thin QR) the SVD of the small ``(W − μ) Rᵀ = Uy S Vᵀ`` gives scores
    ``Uy S`` (f, r) and components ``Q V`` (3p, r).  Also returns the singular values of
    ``B`` (those of ``R``).
    """
    mu = W.mean(axis=0)
    Q, R = np.linalg.qr(B)
    Uy, s, vt = np.linalg.svd((W - mu) @ R.T, full_matrices=False)
    r = int(np.sum(s > s[0] * max(W.shape[0], B.shape[0]) * EPS)) if s[0] > 0 else 0
    comps, scores = _fix_signs(Q @ vt[:r].T, Uy[:, :r] * s[:r])
    basis = PCABasis(neutral.ravel() + B @ mu, comps, s[:r] ** 2 / (W.shape[0] - 1))
    return basis, scores, np.linalg.svd(R, compute_uv=False)


def animation_pca(model: BlendshapeModel, weights: ArrayLike) -> PCABasis:
    """PCA of an animation's frames ``b0 + B w_t`` without forming the f × 3p frame matrix (3.7.8).

    Parameters
    ----------
    model : BlendshapeModel
    weights : array_like, shape (f, n)
        Slider values per frame, ``f ≥ 2``.

    Returns
    -------
    PCABasis
        All components of nonzero variance, by decreasing variance: ``mean`` (3p,),
        ``components`` (3p, r), ``variances`` (r,).
    """
    _, W, B = animation_linear_form(model, weights)
    return _animation_pca(W, B, model.neutral)[0]


# ---------------------------------------------------------------- compression (3.7.8)
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


def _cluster_members(label, n_centres):
    """Vertex order sorted by cluster, each cluster's start in it, and the member lists."""
    order = np.argsort(label, kind="stable")
    starts = np.searchsorted(label[order], np.arange(n_centres))
    return order, starts, np.split(order, starts[1:])


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
    order, starts, members = _cluster_members(label, centres.size)
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


def _compression(model, weights, tol, max_components):
    """:func:`compression_report` and the animation's full PCA basis (computed once for both)."""
    raw, W, B = animation_linear_form(model, weights)
    tol = validate.positive(tol, "tol")
    if max_components is not None:
        max_components = count(max_components, "max_components", 0)
    basis, scores, sv_rig = _animation_pca(W, B, model.neutral)
    r = basis.n_components
    M = r if max_components is None else min(r, max_components)
    errors = _max_vertex_errors(basis.components, scores, M)
    ok = np.flatnonzero(errors <= tol)
    m = int(ok[0]) if ok.size else None
    cut = max(REL_TOL * (model.scale or 1.0), sv_rig[0] * B.shape[0] * EPS)
    diag = {"errors": errors, "n_targets": model.n_targets, "n_frames": raw.shape[0],
            "compression_ratio": None if m is None else (model.n_targets / m if m else np.inf),
            "animation_rank": r, "rig_rank": int(np.sum(sv_rig > cut)), "tol": tol,
            "singular_values": np.sqrt(basis.variances * (raw.shape[0] - 1))}
    if m is None:
        msg = f"{M} components leave a max vertex error of {errors[-1]:.3g} > tol {tol:.3g}"
        return Result(None, status=Status.FAILED, message=msg, diagnostics=diag,
                      issues=[Issue("error", "tolerance_not_met", msg)]), basis
    msg = f"{m} of {model.n_targets} components reach max vertex error {errors[m]:.3g} ≤ {tol:.3g}"
    return Result(m, status=Status.OK, message=msg, diagnostics=diag), basis


def compression_report(model: BlendshapeModel, weights: ArrayLike, tol: float,
                       max_components: int | None = None) -> Result:
    """How many PCA components reproduce an animation to ``tol`` (thesis 3.7.8).

    PCA of the frames :meth:`BlendshapeModel.evaluate` gives (correctives included); the
    error of a rank-``m`` reconstruction is the largest Euclidean 3-D vertex error over all
    frames and vertices, ``max_{t,i} ‖x_t,i − (mean + U_m U_mᵀ (x_t − mean))_i‖``.

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
        ``value``: smallest ``m`` with error ≤ ``tol`` (``None`` and status FAILED if no
        ``m ≤ max_components`` reaches it).  ``diagnostics``: ``errors`` (M + 1,) for m = 0 … M,
        ``n_targets``, ``n_frames``, ``compression_ratio`` (n / m), ``animation_rank``,
        ``rig_rank`` (components reproducing the rig's whole target span), ``singular_values``,
        ``tol``.
    """
    return _compression(model, weights, tol, max_components)[0]


def compressed_animation_pca(model: BlendshapeModel, weights: ArrayLike, tol: float) -> Result:
    """The fewest leading components of an animation's PCA that keep it within ``tol`` (3.7.8).

    Parameters
    ----------
    model : BlendshapeModel
    weights : array_like, shape (f, n)
        Slider values per frame, ``f ≥ 2``.
    tol : float
        Max vertex error (object units), > 0.

    Returns
    -------
    Result
        ``value``: a :class:`PCABasis` of ``max(m, 1)`` components (``m`` from
        :func:`compression_report`), or ``None`` with status FAILED when no ``m`` reaches
        ``tol``; ``message``/``diagnostics`` as :func:`compression_report`.
    """
    report, full = _compression(model, weights, tol, None)
    if report.value is None:
        return report
    return Result(full.truncated(max(int(report.value), 1)), status=report.status, message=report.message,
                  diagnostics=dict(report.diagnostics, components=report.value))


@dataclass
class PCASliders:
    """Shape keys and slider maps of a PCA rig whose sliders are unit-scaled coefficients (3.4.6, 3.7.5).

    Slider ``i`` moves the face along component ``u_i`` by ``unit_i = √variance_i`` per
    unit, so slider values ``s = c / unit`` and ``s = A w + a`` for blendshape weights ``w``.

    Attributes
    ----------
    basis : PCABasis
        ``m`` components over ``p`` vertices.
    unit : ndarray, shape (m,)
    rest : ndarray, shape (p, 3)
        The basis mean (the reference key).
    keys : ndarray, shape (m, p, 3)
        Key ``i`` at ``mean + unit_i u_i``.
    A : ndarray, shape (m, n)
    a : ndarray, shape (m,)
    """

    basis: PCABasis
    unit: np.ndarray
    rest: np.ndarray
    keys: np.ndarray
    A: np.ndarray
    a: np.ndarray

    def slider_values(self, weights: ArrayLike) -> np.ndarray:
        """Slider values ``A w + a``, shape (f, m), of blendshape weights (f, n)."""
        return np.atleast_2d(np.asarray(weights, dtype=np.float64)) @ self.A.T + self.a


def pca_sliders(model: BlendshapeModel, basis: PCABasis, weights: ArrayLike | None = None,
                limit: float | None = None) -> PCASliders:
    """Unit-scaled PCA sliders of ``basis`` for the rig ``model`` (thesis 3.4.6, 3.7.5).

    Slider ``i`` moves the face by ``unit_i`` along ``u_i``: ``unit_i = √variance_i``, grown where needed so
    that the slider values ``s = A w + a`` of every frame of ``weights`` stay within ``±limit`` (a host
    application clamps a key's value, Blender to ±10; a clamped slider would silently miss its frame).

    Parameters
    ----------
    model : BlendshapeModel
        ``n`` targets over ``p`` vertices.
    basis : PCABasis
        ``m`` components over the rig's vertices.
    weights : array_like, shape (f, n), optional
        Frames the sliders must reproduce (with ``limit``).
    limit : float, optional
        Largest slider magnitude, > 0.

    Returns
    -------
    PCASliders
        Keys (m, p, 3) one unit out along each component, and the map ``s = A w + a`` scaled to those
        units.
    """
    A, a = blendshape_to_pca_maps(model, basis)
    unit = np.sqrt(np.maximum(basis.variances, 1e-300))
    if weights is not None and limit is not None:
        W = shaped(weights, "weights", f"(f, {model.n_targets})", ndims=(2,), last=model.n_targets)
        reach = np.abs(W @ A.T + a).max(axis=0, initial=0.0) / validate.positive(limit, "limit")
        unit = np.maximum(unit, reach)
    keys = (basis.mean[None] + (unit * basis.components).T).reshape(basis.n_components, basis.mean.size // 3, 3)
    return PCASliders(basis, unit, basis.mean.reshape(-1, 3), keys, A / unit[:, None], a / unit)
