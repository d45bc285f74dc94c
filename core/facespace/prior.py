"""The face-space Gaussian: a prior over expressions and its plausibility meter (thesis 3.7.9, ch. 6).

J.P. Lewis, *Learning from the Artist*, 2016, 3.7.9 and chapter 6: fit a Gaussian
``N(μ, Σ)`` to the slider vectors of real animation and whiten them,
``z = Λ^{-1/2} Vᵀ (w − μ)``.  In n dimensions ``‖z‖`` is χ-distributed, so the mass sits
in a thin shell of radius ≈ √n and the mean face itself is *atypical*: frames are
flagged both when too extreme and when too average.
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike
from scipy import stats

from .. import validate
from ..errors import ErrorCode
from ..result import Issue, Result, ShapeSpaceError, Status
from ._common import shaped

__all__ = ["FaceGaussian", "fit_face_gaussian", "face_gaussian_from_arrays"]


@dataclass
class FaceGaussian:
    """A Gaussian over face-space weight vectors (thesis 3.7.9, ch. 6).

    Attributes
    ----------
    mean : ndarray, shape (n,)
        ``μ``.
    eigvecs : ndarray, shape (n, n)
        Covariance eigenvectors ``V`` (columns), by decreasing variance.
    eigvals : ndarray, shape (n,)
        Whitening variances ``Λ``: covariance eigenvalues λ_i plus ``ridge``.
    dimension : float
        Effective dimension d = Σ λ_i / (λ_i + ridge) = E‖z‖² under the fitted covariance: n without
        a ridge, about the covariance rank with one.
    ridge : float
    regularised : bool
    message : str
    diagnostics : dict
        ``constant_channels``, ``frames``, ``condition`` (before the ridge).
    """

    mean: np.ndarray
    eigvecs: np.ndarray
    eigvals: np.ndarray
    dimension: float
    ridge: float = 0.0
    regularised: bool = False
    message: str = "ok"
    diagnostics: dict = field(default_factory=dict)

    def _weights(self, w, name: str) -> np.ndarray:
        n = self.mean.size
        return shaped(w, name, f"(..., {n}) ({n} channels)", last=n)

    def whiten(self, w: ArrayLike) -> np.ndarray:
        """``z = Λ^{-1/2} Vᵀ (w − μ)`` for weights ``w`` (..., n); shape (..., n)."""
        w = self._weights(w, "w")
        return ((w - self.mean) @ self.eigvecs) / np.sqrt(self.eigvals)

    def unwhiten(self, z: ArrayLike) -> np.ndarray:
        """Inverse of :meth:`whiten`: ``w = μ + V Λ^{1/2} z`` for ``z`` (..., n); shape (..., n)."""
        z = self._weights(z, "z")
        return self.mean + (z * np.sqrt(self.eigvals)) @ self.eigvecs.T

    def face_norm(self, w: ArrayLike) -> np.ndarray:
        """Mahalanobis distance ``‖z‖`` of ``w`` (..., n) from the mean face; shape (...)."""
        return np.linalg.norm(self.whiten(w), axis=-1)

    @property
    def shell_radius(self) -> float:
        """Mode of the χ distribution with d degrees of freedom, √(d − 1) (0 when d ≤ 1)."""
        return float(np.sqrt(max(self.dimension - 1.0, 0.0)))

    def percentile(self, w: ArrayLike) -> np.ndarray:
        """χ² CDF of ``‖z‖²`` with d degrees of freedom, shape (...): 0 at the mean face, → 1 far out."""
        return stats.chi2.cdf(self.face_norm(w) ** 2, self.dimension)

    def plausibility(self, w: ArrayLike, alpha: float = 0.01) -> Result:
        """Per-frame plausibility of faces ``w`` (..., n) (ch. 6: the mean face is atypical).

        Parameters
        ----------
        w : array_like, shape (..., n)
        alpha : float
            Total probability of the two tails, strictly between 0 and 1.

        Returns
        -------
        Result
            ``value``: array (...) of ``"too_extreme"`` (percentile > 1 − α/2), ``"too_average"``
            (percentile < α/2) or ``"typical"``; status WARNING when any frame is not typical.
            ``diagnostics``: ``norm`` and ``percentile`` (...), ``shell_radius``, ``dimension``, ``alpha``.
        """
        alpha = validate.finite_scalar(alpha, "alpha")
        if not 0 < alpha < 1:
            raise ShapeSpaceError(f"alpha must lie strictly between 0 and 1, got {alpha}", ErrorCode.RANGE)
        norm = self.face_norm(w)
        pct = stats.chi2.cdf(norm ** 2, self.dimension)
        status = np.where(pct > 1 - alpha / 2, "too_extreme", np.where(pct < alpha / 2, "too_average", "typical"))
        issues = [Issue("info", "regularised", self.message)] if self.regularised else []
        flat = status.reshape(-1)
        for code, text in (("too_extreme", "farther from the mean face than real faces get"),
                           ("too_average", "closer to the mean face than real faces get (the mean is atypical)")):
            idx = np.flatnonzero(flat == code)
            if idx.size:
                issues.append(Issue("warning", code, f"{idx.size} frame(s) are {text}",
                                    tuple(f"frame {i}" for i in idx)))
        bad = int(np.count_nonzero(flat != "typical"))
        return Result(status, status=Status.WARNING if bad else Status.OK,
                      message=f"{bad} of {flat.size} frame(s) implausible at α = {alpha:g}",
                      diagnostics={"norm": norm, "percentile": pct, "alpha": alpha, "dimension": self.dimension,
                                   "shell_radius": self.shell_radius}, issues=issues)

    def implausible_frames(self, frames_weights: ArrayLike, alpha: float = 0.01) -> tuple[np.ndarray, list[str]]:
        """The frames that are not typical (see :meth:`plausibility`).

        Parameters
        ----------
        frames_weights : array_like, shape (f, n)
        alpha : float

        Returns
        -------
        idx : ndarray of int, shape (k,)
            Row indices of the implausible frames.
        reasons : list of str, length k
            ``"too_extreme"`` or ``"too_average"``.
        """
        n = self.mean.size
        W = shaped(frames_weights, "frames_weights", f"(frames, {n})", ndims=(2,), last=n)
        status = self.plausibility(W, alpha).value
        idx = np.flatnonzero(status != "typical")
        return idx, [str(s) for s in status[idx]]


def fit_face_gaussian(weights: ArrayLike, ridge: float | None = None) -> FaceGaussian:
    """Fit the face-space Gaussian ``N(μ, Σ)`` to animation frames (thesis 3.7.9, ch. 6).

    Parameters
    ----------
    weights : array_like, shape (f, n)
        Blendshape weights, one row per frame; ``f ≥ 2``, ``n ≥ 1``.
    ridge : float, optional
        Variance added to every covariance eigenvalue.  By default none, unless f ≤ n, a channel is
        constant or the covariance is singular; then 1e-3 × the mean channel variance (1e-6 when every
        channel is constant), said in ``message``.  Constant channels are whitened with the ridge.

    Returns
    -------
    FaceGaussian
        ``mean`` (n,), ``eigvecs`` (n, n), ``eigvals`` (n,) of ``Σ + ridge·I``.
    """
    W = shaped(weights, "weights", "(frames, channels)", ndims=(2,))
    f, n = W.shape
    if f < 2 or n < 1:
        raise ShapeSpaceError(f"weights needs at least 2 frames and 1 channel, got shape {W.shape}",
                              ErrorCode.TOO_FEW)
    if ridge is not None:
        ridge = validate.positive(ridge, "ridge")
    mean = W.mean(axis=0)
    C = np.atleast_2d(np.cov(W, rowvar=False))
    lam, V = np.linalg.eigh(C)
    lam, V = np.clip(lam[::-1], 0.0, None), V[:, ::-1]
    constant = np.flatnonzero(np.ptp(W, axis=0) <= 1e-12 * max(1.0, float(np.abs(W).max())))
    reasons = [text for cond, text in ((f <= n, f"only {f} frames for {n} channels"),
                                       (constant.size, f"{constant.size} constant channel(s) {constant.tolist()}"),
                                       (lam[-1] <= 1e-10 * lam[0], "the covariance is singular")) if cond]
    scale = float(np.mean(np.diag(C)))
    message = f"face Gaussian of {n} channels from {f} frames"
    how = "given"
    if ridge is None and reasons:
        ridge = 1e-3 * scale if scale > 0 else 1e-6
        how = "1e-3 × mean variance" if scale > 0 else "1e-6: every channel is constant"
    ridge = float(ridge or 0.0)
    dim = float(n) if ridge == 0 else max(float(np.sum(lam / (lam + ridge))), 1e-12)
    if ridge:
        why = " because " + ", ".join(reasons) if reasons else ""
        message += f"; regularised with ridge {ridge:.3g} ({how}){why}; effective dimension {dim:.3g}"
    cond = float(lam[0] / lam[-1]) if lam[-1] > 0 else np.inf
    return FaceGaussian(mean, V, lam + ridge, dim, ridge, ridge > 0, message,
                        {"constant_channels": constant.tolist(), "frames": f, "condition": cond})


def _stored_names(names: object) -> list[str]:
    if not isinstance(names, (list, tuple)) or not names or not all(isinstance(n, str) for n in names):
        raise ShapeSpaceError(f"names must be a non-empty list of slider names, got {names!r:.80}", ErrorCode.TYPE)
    dup = sorted(n for n, c in Counter(names).items() if c > 1)
    if dup:
        raise ShapeSpaceError(f"names repeats {', '.join(map(repr, dup))}", ErrorCode.DUPLICATE_NAME)
    return list(names)


def face_gaussian_from_arrays(names: list[str], mean: ArrayLike, eigvecs: ArrayLike, eigvals: ArrayLike,
                              dimension: float, ridge: float = 0.0, regularised: bool = False,
                              message: str = "") -> FaceGaussian:
    """A :class:`FaceGaussian` over the sliders ``names`` from stored arrays, every shape checked.

    What :func:`fit_face_gaussian` gives, read back (from a file, say): the whitening
    ``z = Λ^{-1/2} Vᵀ (w − μ)`` (thesis 3.7.9) needs ``μ`` (n,), orthonormal ``V`` (n, n) and
    ``Λ`` (n,) > 0 for the ``n`` named sliders, and ``0 < d ≤ n``.

    Parameters
    ----------
    names : list of str, length n
        Distinct slider names, n ≥ 1.
    mean : array_like, shape (n,)
    eigvecs : array_like, shape (n, n)
        Orthonormal columns.
    eigvals : array_like, shape (n,)
        Positive whitening variances.
    dimension : float
        Effective dimension, in (0, n].
    ridge : float
        ≥ 0.
    regularised : bool
    message : str

    Returns
    -------
    FaceGaussian
    """
    n = len(_stored_names(names))
    mean = validate.array(mean, "mean", shape=(n,))
    eigvecs = validate.array(eigvecs, "eigvecs", shape=(n, n))
    eigvals = validate.array(eigvals, "eigvals", shape=(n,))
    if np.any(eigvals <= 0):
        raise ShapeSpaceError(f"eigvals must be positive, found {eigvals.min():g}", ErrorCode.RANGE)
    if not np.allclose(eigvecs.T @ eigvecs, np.eye(n), atol=1e-6):
        raise ShapeSpaceError("eigvecs must have orthonormal columns", ErrorCode.NOT_ORTHONORMAL)
    dimension = validate.positive(dimension, "dimension")
    if dimension > n * (1 + 1e-9):
        raise ShapeSpaceError(f"dimension must be at most the {n} sliders, got {dimension:g}", ErrorCode.RANGE)
    ridge = validate.non_negative(ridge, "ridge")
    if not isinstance(regularised, bool) or not isinstance(message, str):
        raise ShapeSpaceError("regularised must be a bool and message a string", ErrorCode.TYPE)
    return FaceGaussian(mean, eigvecs, eigvals, dimension, ridge, regularised, message)
