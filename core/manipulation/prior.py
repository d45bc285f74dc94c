"""The learned prior of direct manipulation (thesis 4.3): training, and its terms in the drag objective.

:class:`WeightPrior` is a Gaussian on slider values learned from earlier
animation by PCA (:func:`train_prior`).  The drag solve uses it either
literally in PCA coefficients (Eq. 4.8, see ``solve._solve_pca``) or — the
default — as a regularised covariance in weight space (:func:`prior_terms`),
which still reaches expressions outside the training span.  Mode snapping
(Eq. 4.9, :func:`snap_term`) pulls the first PCA coefficients toward the
mean of nearby training frames.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import ErrorCode
from ..result import ShapeSpaceError
from ..validate import array

__all__ = ["WeightPrior", "train_prior", "prior_terms", "snap_term"]


@dataclass
class WeightPrior:
    """A Gaussian prior on slider values learned from animation (thesis 4.3).

    Attributes
    ----------
    names : list of str
        Slider names, in the model's order.
    mean : ndarray, shape (n,)
    components : ndarray, shape (n, r)
        Orthonormal principal directions (columns), largest variance first.
    variances : ndarray, shape (r,)
        PCA variances λ_k (> 0).
    coefficients : ndarray, shape (f, r)
        Training frames' PCA coefficients (for mode snapping, Eq. 4.9).
    eps : float
        Covariance regulariser as a fraction of the mean variance.
    """

    names: list
    mean: np.ndarray
    components: np.ndarray
    variances: np.ndarray
    coefficients: np.ndarray
    eps: float = 0.1

    @property
    def unit(self) -> float:
        """Mean variance: the prior's natural unit."""
        return float(self.variances.mean())

    def to_coefficients(self, w: np.ndarray) -> np.ndarray:
        """Affine map ``w → c = Uᵀ(w − mean)``: slider values (n,) or (f, n) to PCA coefficients (r,) or (f, r)."""
        return (np.asarray(w, dtype=np.float64) - self.mean) @ self.components

    def aligned(self, names: Sequence[str]) -> "WeightPrior":
        """This prior re-indexed to a rig's slider order (keys it never saw get no variance).

        Raises
        ------
        ShapeSpaceError
            ``prior_stale`` when the prior knows sliders the rig no longer has.
        """
        names = list(names)
        missing = [n for n in self.names if n not in names]
        if missing:
            raise ShapeSpaceError(
                f"the prior was trained on shape keys that no longer exist: {', '.join(missing[:5])}; "
                "train it again", ErrorCode.PRIOR_STALE)
        if names == list(self.names):
            return self
        pos = [names.index(n) for n in self.names]
        mean = np.zeros(len(names))
        comp = np.zeros((len(names), self.components.shape[1]))
        mean[pos] = self.mean
        comp[pos] = self.components
        return WeightPrior(names, mean, comp, self.variances, self.coefficients, self.eps)


def train_prior(weights: np.ndarray, names: Sequence[str], eps: float = 0.1, energy: float = 1.0) -> WeightPrior:
    """Learn a :class:`WeightPrior` from animation frames (thesis 4.3).

    Parameters
    ----------
    weights : array_like, shape (f, n)
        Slider values of the training frames (e.g. sampled actions).
    names : sequence of str, length n
    eps : float
        Regulariser (fraction of the mean variance) added to the covariance.
    energy : float
        Keep the leading components that explain this fraction of variance
        (default: every direction the data moves in; the regulariser ``eps``
        keeps the rest reachable).

    Returns
    -------
    WeightPrior
        ``r`` components, ``r ≤ min(f, n)``.

    Raises
    ------
    ShapeSpaceError
        Wrong shape, fewer than 2 frames, non-finite values, or no slider varies.
    """
    names = list(names)
    w = array(weights, "weights", finite=False)
    if w.ndim != 2 or w.shape[1] != len(names):
        raise ShapeSpaceError(f"weights must have shape (frames, {len(names)}), got {w.shape}", ErrorCode.SHAPE)
    if w.shape[0] < 2:
        raise ShapeSpaceError(f"a prior needs at least 2 frames of animation, got {w.shape[0]}",
                              ErrorCode.PRIOR_FRAMES)
    if not np.isfinite(w).all():
        raise ShapeSpaceError("the training animation contains NaN or infinite values", ErrorCode.NON_FINITE)
    mean = w.mean(axis=0)
    centred = w - mean
    _, sv, vt = np.linalg.svd(centred, full_matrices=False)
    var = sv ** 2 / max(w.shape[0] - 1, 1)
    if var.size == 0 or var[0] <= 1e-12:
        raise ShapeSpaceError("the training animation moves none of the shape keys", ErrorCode.PRIOR_CONSTANT)
    cum = np.cumsum(var) / var.sum()
    r = var.size if energy >= 1.0 else int(np.searchsorted(cum, energy) + 1)
    r = max(1, min(r, int(np.sum(var > 1e-12 * var[0]))))
    comp = vt[:r].T
    return WeightPrior(names, mean, comp, var[:r], centred @ comp, eps)


def prior_terms(prior: WeightPrior, alpha: float, w0: np.ndarray,
                pca_snap: tuple | None = None) -> tuple[float, list, list, np.ndarray]:
    """The learned prior as identity weight, low-rank columns, signs and linear term (covariance form).

    The plain ``α‖w − w0‖²`` of Eq. 4.5 becomes ``α (w − w0)ᵀ P (w − w0)``
    with the prior metric ``P = σ̄² (Σ_r + ε σ̄² I)⁻¹ = (1/ε) I − U diag(γ) Uᵀ``,
    ``γ_k = 1/ε − σ̄²/(λ_k + ε σ̄²) ≥ 0``: moves along the training data's
    principal directions are cheap, moves outside its span cost ``1/ε`` times
    the plain mode's, so every expression stays reachable.

    Parameters
    ----------
    prior : WeightPrior
        Aligned to the rig (n sliders).
    alpha : float
    w0 : ndarray, shape (n,)
    pca_snap : (U3, target, beta), optional
        Mode-snapping term of Eq. 4.9 (:func:`snap_term` plus its weight), added as ``β‖U3ᵀw − target‖²``.

    Returns
    -------
    a : float
        Identity weight.
    cols : list of ndarray, each (n, r_i)
    signs : list of ndarray, each (r_i,)
        The regulariser is ``a‖w‖² + Σ_i (cols_iᵀ w)ᵀ diag(signs_i) (cols_iᵀ w) − 2 linᵀ w + const``.
    lin : ndarray, shape (n,)
    """
    unit = prior.unit
    e = prior.eps * unit
    gamma = 1.0 / prior.eps - unit / (prior.variances + e)
    keep = gamma > 1e-12
    U = prior.components[:, keep]
    a = alpha / prior.eps
    cols = [U]
    sgn = [-alpha * gamma[keep]]
    lin = a * w0 - U @ (alpha * gamma[keep] * (U.T @ w0))
    if pca_snap is not None:
        U3, target, beta = pca_snap
        cols.append(U3)
        sgn.append(np.full(U3.shape[1], beta))
        lin = lin + U3 @ (beta * target)
    return a, cols, sgn, lin


def snap_term(prior: WeightPrior, w: np.ndarray, dims: int = 3) -> tuple[tuple | None, int]:
    """Mode snapping, thesis Eq. 4.9: where nearby training frames pull the first PCA coefficients.

    The neighbours are the training frames whose coefficients lie within
    ``σ_i/3`` of ``w``'s in each of the first ``dims`` PCA dimensions.

    Parameters
    ----------
    prior : WeightPrior
        Aligned to the rig (n sliders).
    w : ndarray, shape (n,)
    dims : int

    Returns
    -------
    term : (U3, target) or None
        ``U3`` (n, d) whitened to the prior unit and ``target`` (d,): the snap
        penalty is ``‖U3ᵀw − target‖²``.  ``None`` when no frame is near.
    count : int
        Number of neighbouring training frames.
    """
    d = min(dims, prior.components.shape[1])
    c = prior.to_coefficients(w)[:d]
    sigma = np.sqrt(prior.variances[:d])
    near = np.all(np.abs(prior.coefficients[:, :d] - c) <= sigma / 3.0, axis=1)
    if not near.any():
        return None, 0
    target_c = prior.coefficients[near, :d].mean(axis=0)
    U3 = prior.components[:, :d] / np.sqrt(prior.variances[:d] / prior.unit)   # whitened to the prior unit
    return (U3, target_c / np.sqrt(prior.variances[:d] / prior.unit) + U3.T @ prior.mean), int(near.sum())
