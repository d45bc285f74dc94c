"""Pose-space confidence: Gaussian-process variance of the interpolation (thesis 9.1–9.2)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import cho_solve, solve_triangular

from .. import rbf
from ..result import ShapeSpaceError

__all__ = ["GPConfidence", "gp_variance", "vertex_uncertainty"]

#: Positive-definite kernels a Gaussian process can use (the conditionally positive definite
#: polyharmonic kernels of the RBF toolkit cannot serve as covariances).
GP_KERNELS = ("gaussian", "inverse_multiquadric", "inverse_quadratic")


def _trailing(a, name: str, n: int, what: str = "channels") -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    if a.ndim < 1 or a.shape[-1] != n:
        raise ShapeSpaceError(f"{name} must have shape (..., {n}) ({n} {what}), got {a.shape}", "shape")
    if not np.isfinite(a).all():
        raise ShapeSpaceError(f"{name} contains NaN or infinite values", "non_finite")
    return a


# ------------------------------------------------------------------ pose-space confidence (9.1–9.2)
@dataclass
class GPConfidence:
    """Gaussian-process confidence of pose-space interpolation (thesis 9.1–9.2).

    Covariance k(x, y) = φ(ε‖x − y‖) / φ(0) with φ and the ε scaling of :data:`core.rbf.KERNELS` (prior
    variance 1).  Build with :meth:`fit`: the Cholesky factor of K + (noise + jitter) I is computed
    once, so :meth:`variance` costs one kernel row and one triangular solve per pose.
    """

    centers: np.ndarray
    kernel: str
    epsilon: float
    noise: float
    jitter: float
    chol: np.ndarray                     # lower triangular (N, N)

    @classmethod
    def fit(cls, centers, kernel: str = "gaussian", epsilon: float = 1.0, noise: float = 0.0) -> "GPConfidence":
        """Factor the kernel matrix of ``centers`` (N, d); ``kernel`` one of :data:`GP_KERNELS`.

        ``noise`` σ² is added to the diagonal; when K is numerically singular (duplicate or very close
        centres) a jitter of at most 1e-6 is added too and recorded in ``jitter``.
        """
        X = np.asarray(centers, dtype=np.float64)
        if X.ndim != 2 or X.shape[0] < 1:
            raise ShapeSpaceError(f"centers must have shape (N, d) with N ≥ 1, got {X.shape}", "shape")
        if not np.isfinite(X).all():
            raise ShapeSpaceError("centers contains NaN or infinite values", "non_finite")
        if kernel not in GP_KERNELS:
            raise ShapeSpaceError(f"kernel must be one of {', '.join(GP_KERNELS)} (positive definite), "
                                  f"got {kernel!r}", "kernel")
        if not (np.isfinite(epsilon) and epsilon > 0):
            raise ShapeSpaceError(f"epsilon must be positive and finite, got {epsilon}", "range")
        if not (np.isfinite(noise) and noise >= 0):
            raise ShapeSpaceError(f"noise must be non-negative and finite, got {noise}", "range")
        conf = cls(X, kernel, float(epsilon), float(noise), 0.0, None)
        K = conf.kernel_row(X)
        for jitter in (0.0, 1e-12, 1e-10, 1e-8, 1e-6):
            try:
                conf.chol = np.linalg.cholesky(K + (noise + jitter) * np.eye(X.shape[0]))
                conf.jitter = jitter
                return conf
            except np.linalg.LinAlgError:
                continue
        raise ShapeSpaceError("the kernel matrix is singular even with jitter; add noise", "singular")

    def kernel_row(self, x) -> np.ndarray:
        """Normalised kernel values k(x, centres) for ``x`` (..., d), shape (..., N)."""
        x = _trailing(np.atleast_1d(x), "x", self.centers.shape[1], "pose dimensions")
        phi = rbf.KERNELS[self.kernel][0]
        k = phi(self.epsilon * rbf.pairwise_distances(x.reshape(-1, x.shape[-1]), self.centers)) / phi(0.0)
        return k.reshape(x.shape[:-1] + (self.centers.shape[0],))

    def variance(self, x) -> np.ndarray:
        """Posterior variance 1 − k_xᵀ (K + σ² I)⁻¹ k_x at poses ``x`` (..., d), shape (...), in [0, 1].

        The variance of the interpolated function itself (σ² is not added back).
        """
        k = self.kernel_row(x)
        v = solve_triangular(self.chol, k.reshape(-1, k.shape[-1]).T, lower=True, check_finite=False)
        return np.clip(1.0 - np.sum(v * v, axis=0), 0.0, 1.0).reshape(k.shape[:-1])


def gp_variance(centers, x, kernel: str = "gaussian", epsilon: float = 1.0, noise: float = 0.0) -> np.ndarray:
    """Gaussian-process posterior variance at ``x`` (..., d) given ``centers`` (N, d), shape (...).

    0 at the centres (noise 0), → 1 far from them.  :class:`GPConfidence` reuses one factorisation.
    """
    return GPConfidence.fit(centers, kernel, epsilon, noise).variance(x)


def vertex_uncertainty(conf: GPConfidence, x, correctives) -> np.ndarray:
    """Per-vertex predictive standard deviation s_v √variance(x) (thesis 9.1–9.2).

    s_v² = y_vᵀ (K + σ² I)⁻¹ y_v / (3N) is the maximum-likelihood output scale of vertex v's corrective
    values y_v (N × 3, summed over coordinates): a vertex no example moves has zero uncertainty, and a
    heat map of the result shows where a new example would matter.

    Parameters
    ----------
    conf : GPConfidence
    x : array_like, shape (..., d)
        Pose(s).
    correctives : array_like, shape (N, p, 3)

    Returns
    -------
    ndarray, shape (..., p)
    """
    if not isinstance(conf, GPConfidence):
        raise ShapeSpaceError("conf must be a GPConfidence (see GPConfidence.fit)", "type")
    N = conf.centers.shape[0]
    Y = np.asarray(correctives, dtype=np.float64)
    if Y.ndim != 3 or Y.shape[0] != N or Y.shape[2] != 3:
        raise ShapeSpaceError(f"correctives must have shape ({N}, p, 3), got {Y.shape}", "shape")
    if not np.isfinite(Y).all():
        raise ShapeSpaceError("correctives contains NaN or infinite values", "non_finite")
    A = solve_triangular(conf.chol, Y.reshape(N, -1), lower=True, check_finite=False)
    scale = np.sqrt((A * A).reshape(N, -1, 3).sum(axis=(0, 2)) / (3.0 * N))
    return scale * np.sqrt(conf.variance(x))[..., None]
