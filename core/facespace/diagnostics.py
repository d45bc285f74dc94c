"""Diagnostics of a rig's targets: empty targets, coherence, near-duplicates, sparsity (thesis 3.7).

J.P. Lewis, *Learning from the Artist*, 2016: 3.7.1 / 3.7.6 and Fig. 3.12 the
coherence ``|⟨d_i, d_j⟩| / (‖d_i‖ ‖d_j‖)`` of the target displacements (near 1:
the two targets nearly duplicate each other, so their weights are ill determined);
Figs 3.14 / 3.15 the sparsity of an animation's blendshape weights compared with
its PCA coefficients — the reason artists animate blendshapes, not components.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .. import validate
from ..blendshape import BlendshapeModel
from ..errors import ErrorCode
from ..result import Result, ShapeSpaceError, Status
from ._common import REL_TOL, check_model, count
from .pca import PCABasis, animation_linear_form, animation_pca, check_basis

__all__ = ["empty_targets", "coherence_matrix", "mutual_coherence", "similar_pairs", "coherence_image",
           "sparsity_comparison"]


def _empty_mask(model, rel_tol):
    check_model(model, need_targets=False)
    limit = validate.positive(rel_tol, "rel_tol") * (model.scale or 1.0)
    if model.deltas.size == 0:
        return np.zeros(model.n_targets, bool)
    return np.linalg.norm(model.deltas, axis=2).max(axis=1) <= limit


def empty_targets(model: BlendshapeModel, rel_tol: float = REL_TOL) -> list[str]:
    """Names of the targets that move no vertex (thesis 3.7.1).

    Parameters
    ----------
    model : BlendshapeModel
    rel_tol : float
        A target is empty when its largest vertex displacement ``max_i ‖d_k,i‖`` is
        ≤ ``rel_tol`` × the neutral's bounding-box diagonal.

    Returns
    -------
    list of str
    """
    return [model.names[k] for k in np.flatnonzero(_empty_mask(model, rel_tol))]


def coherence_matrix(model: BlendshapeModel, rel_tol: float = REL_TOL) -> np.ndarray:
    """Target coherence ``C_ij = |⟨d_i, d_j⟩| / (‖d_i‖ ‖d_j‖)`` (thesis 3.7.1, 3.7.6, Fig. 3.12).

    Parameters
    ----------
    model : BlendshapeModel
        ``n`` targets.
    rel_tol : float
        Threshold of :func:`empty_targets`.

    Returns
    -------
    ndarray, shape (n, n)
        Symmetric, in [0, 1], unit diagonal; rows, columns and diagonal entries of
        :func:`empty_targets` are 0 (a 0 on the diagonal lists them).
    """
    live = ~_empty_mask(model, rel_tol)
    flat = model.deltas.reshape(model.n_targets, 3 * model.n_vertices)
    unit = np.where(live[:, None], flat, 0.0)
    unit[live] /= np.linalg.norm(flat[live], axis=1)[:, None]
    C = np.minimum(np.abs(unit @ unit.T), 1.0)
    C[np.diag_indices_from(C)] = live
    return C


def mutual_coherence(model: BlendshapeModel, rel_tol: float = REL_TOL) -> float:
    """Largest off-diagonal coherence ``max_{i≠j} C_ij`` of the targets (0 with fewer than two; 3.7.6)."""
    C = coherence_matrix(model, rel_tol)
    return float((C - np.diag(np.diag(C))).max()) if C.shape[0] > 1 else 0.0


def similar_pairs(model: BlendshapeModel, threshold: float = 0.95,
                  rel_tol: float = REL_TOL) -> list[tuple[str, str, float]]:
    """Near-duplicate targets: ``(name_i, name_j, C_ij)`` for ``i < j`` with ``C_ij ≥ threshold`` (3.7.6).

    Parameters
    ----------
    model : BlendshapeModel
    threshold : float
        In (0, 1].
    rel_tol : float
        Threshold of :func:`empty_targets`.

    Returns
    -------
    list of (str, str, float)
        Most similar first.
    """
    if not 0 < threshold <= 1:
        raise ShapeSpaceError(f"threshold must be in (0, 1], got {threshold}", ErrorCode.RANGE)
    C = coherence_matrix(model, rel_tol)
    ii, jj = np.nonzero(np.triu(C >= threshold, k=1))
    return sorted([(model.names[i], model.names[j], float(C[i, j])) for i, j in zip(ii, jj)],
                  key=lambda t: -t[2])


# Samples of a viridis-like ramp (dark purple → blue → green → yellow), RGB 0–255.
_RAMP = np.array([[68, 1, 84], [72, 40, 120], [62, 74, 137], [49, 104, 142], [38, 130, 142],
                  [31, 158, 137], [53, 183, 121], [109, 205, 89], [180, 222, 44], [253, 231, 37]], float)


def coherence_image(C: ArrayLike, size: int | None = None) -> np.ndarray:
    """Heat map of a coherence matrix (thesis Fig. 3.12) as RGBA uint8.

    0 is dark purple and 1 bright yellow, so the unit diagonal stands out.  Row 0 of the
    array is target 0 (top of the picture); Blender images start at the bottom row, so a
    bridge flips it (``[::-1]``) before filling pixels.

    Parameters
    ----------
    C : array_like, shape (n, n)
        Clipped to [0, 1]; NaN shows as 0.
    size : int, optional
        Approximate side in pixels (default 256); ``cell = max(1, size // n)``.

    Returns
    -------
    ndarray of uint8, shape (n·cell, n·cell, 4)
    """
    C = validate.array(C, "C", finite=False)
    if C.ndim != 2 or C.shape[0] != C.shape[1] or C.shape[0] == 0:
        raise ShapeSpaceError(f"C must have shape (n, n) with n ≥ 1, got {C.shape}", ErrorCode.SHAPE)
    size = 256 if size is None else count(size, "size", 1)
    cell = max(1, size // C.shape[0])
    t = np.clip(np.nan_to_num(C, nan=0.0), 0.0, 1.0) * (len(_RAMP) - 1)
    k = np.minimum(t.astype(int), len(_RAMP) - 2)
    rgb = _RAMP[k] + (t - k)[..., None] * (_RAMP[k + 1] - _RAMP[k])
    rgba = np.concatenate([np.rint(rgb), np.full(C.shape + (1,), 255.0)], axis=-1).astype(np.uint8)
    return np.repeat(np.repeat(rgba, cell, axis=0), cell, axis=1)


# ---------------------------------------------------------------- sparsity (Figs 3.14, 3.15)
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


def sparsity_comparison(model: BlendshapeModel, weights: ArrayLike, basis: PCABasis | None = None) -> Result:
    """Sparsity of an animation's blendshape weights versus its PCA coefficients (thesis Figs 3.14, 3.15).

    Blendshape form: effective weights ``w`` (f, n); the energy of target ``k`` is its
    contribution's squared norm ``‖w_k d_k‖²`` (targets are not orthogonal, so these need
    not add up to the frame's).  PCA form: ``c = Uᵀ(x_t − mean)`` centred over the frames
    (``basis`` default: PCA of this animation), energy ``c_k²`` (``U`` is orthonormal).
    Per form, over frames with a nonzero coefficient vector: mean Hoyer sparsity
    ``(√k − L1/L2)/(√k − 1)`` (1 = one nonzero, 0 = all equal) of the raw coefficients
    (``hoyer``) and of each coefficient divided by its RMS over the animation
    (``hoyer_rms``: PCA's raw coefficients are ordered by variance, which alone makes them
    look sparse per frame); ``small_fraction``, coefficients at most 1 % of the frame's
    largest; ``count_95_energy``, coefficients holding 95 % of the frame's energy.  And
    ``curve_small_fraction``: samples at most 1 % of their own curve's largest over the
    animation (the per-curve view of the figures).

    Parameters
    ----------
    model : BlendshapeModel
    weights : array_like, shape (f, n)
    basis : PCABasis, optional
        ``m`` components over the rig's vertices.

    Returns
    -------
    Result
        ``value = {"blendshape": {...}, "pca": {...}}``, each also with ``n_coefficients``
        and ``zero_frames``; NaN where no frame has a nonzero coefficient.
    """
    raw, W, B = animation_linear_form(model, weights)
    basis = animation_pca(model, raw) if basis is None else basis
    check_basis(model, basis)
    U = basis.components
    c = W @ (U.T @ B).T + U.T @ (model.neutral.ravel() - basis.mean)
    c -= c.mean(axis=0)
    w = W[:, :model.n_targets]
    bs = _sparsity(w, w ** 2 * (model.deltas.reshape(model.n_targets, -1) ** 2).sum(axis=1))
    pc = _sparsity(c, c ** 2)
    msg = (f"blendshape ({model.n_targets} weights) vs PCA ({basis.n_components} coefficients): Hoyer "
           f"{bs['hoyer']:.2f} vs {pc['hoyer']:.2f}, RMS-scaled {bs['hoyer_rms']:.2f} vs {pc['hoyer_rms']:.2f}, "
           f"idle curve samples {bs['curve_small_fraction']:.2f} vs {pc['curve_small_fraction']:.2f}")
    return Result({"blendshape": bs, "pca": pc}, status=Status.OK, message=msg,
                  diagnostics={"n_frames": raw.shape[0], "n_targets": model.n_targets,
                               "n_components": basis.n_components})
