"""Pose-space confidence: Gaussian-process variance of the interpolation (thesis 9.1–9.2).

Treating the pose-space interpolant as the mean of a Gaussian process over
pose space gives, for free, a variance: 0 at an example, growing to the prior
variance 1 far from all of them.  It tells the rigger how well the examples
cover the current pose (:class:`GPConfidence`, :func:`gp_variance`), and,
scaled by each vertex's corrective magnitude, where on the mesh a new example
would matter (:func:`vertex_uncertainty`, :func:`heat_map_colors`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.linalg import solve_triangular

from .. import rbf, validate
from ..errors import ErrorCode
from ..result import ShapeSpaceError

__all__ = ["GP_KERNELS", "GPConfidence", "gp_variance", "vertex_uncertainty", "heat_map_colors"]

#: Positive-definite kernels a Gaussian process can use (the conditionally positive definite
#: polyharmonic kernels of the RBF toolkit cannot serve as covariances).
GP_KERNELS = ("gaussian", "inverse_multiquadric", "inverse_quadratic")


@dataclass
class GPConfidence:
    """Gaussian-process confidence of pose-space interpolation (thesis 9.1–9.2).

    Covariance k(x, y) = φ(ε‖x − y‖) / φ(0) with φ and the ε scaling of :data:`core.rbf.KERNELS` (prior
    variance 1).  Build with :meth:`fit`: the Cholesky factor of K + (noise + jitter) I is computed
    once, so :meth:`variance` costs one kernel row and one triangular solve per pose.

    Attributes
    ----------
    centers : ndarray, shape (N, d)
        The examples' poses.
    kernel : str
        One of :data:`GP_KERNELS`.
    epsilon : float
        Kernel width (as in :func:`core.rbf.fit_rbf`).
    noise : float
        Observation noise σ² on the diagonal.
    jitter : float
        Extra diagonal added to make K numerically positive definite (0 unless needed).
    chol : ndarray, shape (N, N)
        Lower Cholesky factor of K + (noise + jitter) I.
    """

    centers: np.ndarray
    kernel: str
    epsilon: float
    noise: float
    jitter: float
    chol: np.ndarray

    @classmethod
    def fit(cls, centers: ArrayLike, kernel: str = "gaussian", epsilon: float = 1.0,
            noise: float = 0.0) -> GPConfidence:
        """Factor the kernel matrix of the examples' poses.

        Parameters
        ----------
        centers : array_like, shape (N, d)
            N ≥ 1 poses.
        kernel : str
            One of :data:`GP_KERNELS`.
        epsilon : float
            Kernel width, > 0.
        noise : float
            σ² ≥ 0 added to the diagonal.  When K is numerically singular (duplicate or very close
            centres) a jitter of at most 1e-6 is added too and recorded in ``jitter``.

        Returns
        -------
        GPConfidence
        """
        X = validate.array(centers, "centers", shape=(None, None))
        if X.shape[0] < 1:
            raise ShapeSpaceError(f"centers must have shape (N, d) with N ≥ 1, got {X.shape}", ErrorCode.SHAPE)
        validate.choice(kernel, "kernel", GP_KERNELS, ErrorCode.KERNEL)
        if not (np.isfinite(epsilon) and epsilon > 0):
            raise ShapeSpaceError(f"epsilon must be positive and finite, got {epsilon}", ErrorCode.RANGE)
        if not (np.isfinite(noise) and noise >= 0):
            raise ShapeSpaceError(f"noise must be non-negative and finite, got {noise}", ErrorCode.RANGE)
        conf = cls(X, kernel, float(epsilon), float(noise), 0.0, None)
        K = conf.kernel_row(X)
        for jitter in (0.0, 1e-12, 1e-10, 1e-8, 1e-6):
            try:
                conf.chol = np.linalg.cholesky(K + (noise + jitter) * np.eye(X.shape[0]))
                conf.jitter = jitter
                return conf
            except np.linalg.LinAlgError:
                continue
        raise ShapeSpaceError("the kernel matrix is singular even with jitter; add noise", ErrorCode.SINGULAR)

    def kernel_row(self, x: ArrayLike) -> np.ndarray:
        """Normalised kernel values k(x, centres) at poses ``x`` (..., d), shape (..., N)."""
        d = self.centers.shape[1]
        x = validate.array(np.atleast_1d(x), "x")
        if x.shape[-1] != d:
            raise ShapeSpaceError(f"x must have shape (..., {d}) ({d} pose dimensions), got {x.shape}",
                                  ErrorCode.SHAPE)
        phi = rbf.KERNELS[self.kernel][0]
        k = phi(self.epsilon * rbf.pairwise_distances(x.reshape(-1, d), self.centers)) / phi(0.0)
        return k.reshape(x.shape[:-1] + (self.centers.shape[0],))

    def variance(self, x: ArrayLike) -> np.ndarray:
        """Posterior variance 1 − k_xᵀ (K + σ² I)⁻¹ k_x at poses ``x`` (..., d), shape (...), in [0, 1].

        The variance of the interpolated function itself (σ² is not added back).
        """
        k = self.kernel_row(x)
        v = solve_triangular(self.chol, k.reshape(-1, k.shape[-1]).T, lower=True, check_finite=False)
        return np.clip(1.0 - np.sum(v * v, axis=0), 0.0, 1.0).reshape(k.shape[:-1])


def gp_variance(centers: ArrayLike, x: ArrayLike, kernel: str = "gaussian", epsilon: float = 1.0,
                noise: float = 0.0) -> np.ndarray:
    """Gaussian-process posterior variance at poses ``x`` given the examples' poses (thesis 9.1).

    0 at the centres (noise 0), → 1 far from them.  :class:`GPConfidence` reuses one factorisation.

    Parameters
    ----------
    centers : array_like, shape (N, d)
    x : array_like, shape (..., d)
    kernel, epsilon, noise
        As :meth:`GPConfidence.fit`.

    Returns
    -------
    ndarray, shape (...)
    """
    return GPConfidence.fit(centers, kernel, epsilon, noise).variance(x)


def vertex_uncertainty(conf: GPConfidence, x: ArrayLike, correctives: ArrayLike) -> np.ndarray:
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
        raise ShapeSpaceError("conf must be a GPConfidence (see GPConfidence.fit)", ErrorCode.TYPE)
    N = conf.centers.shape[0]
    Y = np.asarray(correctives, dtype=np.float64)
    if Y.ndim != 3 or Y.shape[0] != N or Y.shape[2] != 3:
        raise ShapeSpaceError(f"correctives must have shape ({N}, p, 3), got {Y.shape}", ErrorCode.SHAPE)
    Y = validate.array(Y, "correctives")
    A = solve_triangular(conf.chol, Y.reshape(N, -1), lower=True, check_finite=False)
    scale = np.sqrt((A * A).reshape(N, -1, 3).sum(axis=(0, 2)) / (3.0 * N))
    return scale * np.sqrt(conf.variance(x))[..., None]


def heat_map_colors(sd: ArrayLike) -> np.ndarray:
    """RGBA heat-map colours of per-vertex uncertainties (blue: certain → red: the most uncertain vertex).

    Parameters
    ----------
    sd : array_like, shape (p,)
        Non-negative per-vertex standard deviations (:func:`vertex_uncertainty` at one pose).

    Returns
    -------
    ndarray, shape (p, 4)
        ``(t, 0.2 (1 − t), 1 − t, 1)`` with ``t = sd / max(sd)`` (all blue when nothing is uncertain).
    """
    sd = validate.array(sd, "sd", ndim=1)
    top = float(sd.max()) if sd.size else 0.0
    t = np.clip(sd / (top or 1.0), 0.0, 1.0)
    return np.column_stack([t, 0.2 * (1 - t), 1.0 - t, np.ones_like(t)])
