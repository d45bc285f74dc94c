"""Scattered interpolation for pose space (thesis ch. 8).

Radial basis functions with an optional polynomial term (Eq. 8.4 block
system), weight-decay regularisation (Eq. 8.3), normalised RBF, cardinal
interpolation, Shepard's method, linear interpolation on simplices
(Delaunay), and kernel-width selection by leave-one-out cross validation
(Rippa's closed form).  Every interpolant here is *linear in the data*, so
each can also return its **cardinal weights** ``c(x)`` with ``f(x) = c(x)·d``
— the form pose-space deformation needs (one weight per example, applied to
whole sculpted shapes).

Kernel names and scaling follow ``scipy.interpolate.RBFInterpolator``
(``φ(ε r)``), and where both offer the same model the results agree to
rounding (``tests/core/test_rbf.py`` checks every kernel and degree against
scipy, and the other schemes against independent hand computations and
``scipy.interpolate.LinearNDInterpolator``).

Library API
-----------
:func:`fit_rbf` / :class:`RBFInterpolant`
    RBF plus polynomial (Eq. 8.4) with weight decay (Eq. 8.3) — used by
    PSD, Shape-by-Example, scalar drivers and the retarget warp.
:func:`loo_errors`, :func:`choose_epsilon`
    Leave-one-out errors in closed form and the kernel width they select.
:func:`fit_normalized_rbf` / :class:`NormalizedRBF`, :class:`Shepard`, :class:`SimplexLinear`
    The other cardinal schemes of chapter 8 (normalised RBF, inverse
    distance weighting, linear on simplices), for comparing interpolants of
    the same examples.
:func:`pairwise_distances`, :data:`KERNELS`
    Shared building blocks.
"""
from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations_with_replacement

import numpy as np
from numpy.typing import ArrayLike
from scipy.linalg import lu_factor, lu_solve
from scipy.spatial import Delaunay, cKDTree
from scipy.spatial.distance import cdist

from . import validate
from .errors import ErrorCode
from .result import ShapeSpaceError

__all__ = [
    "KERNELS", "RBFInterpolant", "fit_rbf", "NormalizedRBF", "fit_normalized_rbf", "Shepard",
    "SimplexLinear", "loo_errors", "choose_epsilon", "pairwise_distances",
]


def _polyharmonic(k):
    if k % 2:
        return lambda r: r ** k
    return lambda r: np.where(r > 0, r ** k * np.log(np.where(r > 0, r, 1.0)), 0.0)


#: name → (φ(r) on scaled distance r = ε·dist, minimum polynomial degree)
KERNELS = {
    "gaussian": (lambda r: np.exp(-r * r), -1),
    "multiquadric": (lambda r: -np.sqrt(1.0 + r * r), 0),
    "inverse_multiquadric": (lambda r: 1.0 / np.sqrt(1.0 + r * r), -1),
    "inverse_quadratic": (lambda r: 1.0 / (1.0 + r * r), -1),
    "linear": (lambda r: -r, 0),
    "thin_plate_spline": (_polyharmonic(2), 1),
    "cubic": (_polyharmonic(3), 1),
    "quintic": (lambda r: -r ** 5, 2),
    "polyharmonic4": (lambda r: -_polyharmonic(4)(r), 2),
}

#: Kernels that are positive everywhere (what a normalised RBF can divide by).
POSITIVE_KERNELS = ("gaussian", "inverse_multiquadric", "inverse_quadratic")


def pairwise_distances(a: ArrayLike, b: ArrayLike) -> np.ndarray:
    """Euclidean distances between rows of two point sets.

    Parameters
    ----------
    a : array_like, shape (m, d)
    b : array_like, shape (k, d)

    Returns
    -------
    ndarray, shape (m, k)
    """
    return cdist(np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))


def _points(x, name: str, dim: int | None = None) -> np.ndarray:
    """Points as (n, d); a 1-D array is n points in 1-D (or one point when ``dim`` > 1)."""
    x = validate.array(x, name, ndim=(1, 2))
    if x.ndim == 1:
        x = x[:, None] if dim in (None, 1) else x[None, :]
    if dim is not None and x.shape[1] != dim:
        raise ShapeSpaceError(f"{name} must have {dim} columns, got shape {x.shape}", ErrorCode.SHAPE)
    return x


def _epsilon(epsilon) -> float:
    if not (np.isfinite(epsilon) and epsilon > 0):
        raise ShapeSpaceError(f"epsilon must be positive and finite, got {epsilon}", ErrorCode.RANGE)
    return float(epsilon)


def _monomial_powers(dim, degree):
    if degree < 0:
        return np.zeros((0, dim), dtype=int)
    out = []
    for deg in range(degree + 1):
        for combo in combinations_with_replacement(range(dim), deg):
            p = np.zeros(dim, dtype=int)
            for c in combo:
                p[c] += 1
            out.append(p)
    return np.array(out, dtype=int)


def _poly_matrix(x, shift, scale, powers):
    xs = (x - shift) / scale
    return np.prod(xs[:, None, :] ** powers[None, :, :], axis=2)


@dataclass
class RBFInterpolant:
    """A fitted RBF interpolant ``f(x) = Σ_k w_k φ(ε‖x − x_k‖) + p(x)`` (Eq. 8.4).

    Build with :func:`fit_rbf`.

    Attributes
    ----------
    centers : ndarray, shape (K, d)
    kernel : str
    epsilon : float
    degree : int
        Polynomial degree (−1 for none).
    smoothing : float
        Weight-decay regulariser λ (Eq. 8.3), added to the kernel matrix diagonal.
    """

    centers: np.ndarray
    kernel: str
    epsilon: float
    degree: int
    smoothing: float
    _lu: tuple
    _shift: np.ndarray
    _scale: np.ndarray
    _powers: np.ndarray
    _coeffs: np.ndarray = None

    @property
    def n_centers(self) -> int:
        """Number of centres K."""
        return self.centers.shape[0]

    def basis(self, x: ArrayLike) -> np.ndarray:
        """Kernel and polynomial values at ``x`` (m, d), shape (m, K + P)."""
        x = _points(x, "x", self.centers.shape[1])
        phi = KERNELS[self.kernel][0](self.epsilon * pairwise_distances(x, self.centers))
        return np.hstack([phi, _poly_matrix(x, self._shift, self._scale, self._powers)])

    def cardinal(self, x: ArrayLike) -> np.ndarray:
        """Cardinal weights ``c(x)`` at ``x`` (m, d), shape (m, K).

        ``f(x) = c(x) @ values``, and ``c_k(x_j) = δ_kj`` when λ = 0.
        """
        B = self.basis(x)
        K = self.n_centers
        # c(x) = B(x) A⁻¹[:, :K]  ⇔  c(x)ᵀ = A⁻ᵀ B(x)ᵀ restricted to the first K rows
        sol = lu_solve(self._lu, B.T, trans=1)
        return sol[:K].T

    def __call__(self, x: ArrayLike) -> np.ndarray:
        """Interpolated values at ``x`` (m, d), shape (m, ...) matching the fitted values' trailing shape."""
        if self._coeffs is None:
            raise ShapeSpaceError("this interpolant was fitted without values; use cardinal()", ErrorCode.NO_VALUES)
        B = self.basis(x)
        out = B @ self._coeffs.reshape(self._coeffs.shape[0], -1)
        return out.reshape((B.shape[0],) + self._coeffs.shape[1:])


def _default_degree(kernel):
    """scipy's default: the kernel's minimum degree, at least 0."""
    return max(KERNELS[kernel][1], 0)


def _check_solvable(x, P, degree, smoothing):
    """Scale-invariant singularity tests: coincident centres (without smoothing) and a polynomial the
    centres cannot determine make the block system singular whatever the units."""
    K = x.shape[0]
    if smoothing == 0 and K > 1:
        d = pairwise_distances(x, x)
        np.fill_diagonal(d, np.inf)
        spread = float(np.max(np.ptp(x, axis=0))) or 1.0
        if d.min() <= 1e-12 * spread:
            raise ShapeSpaceError("the interpolation system is singular: two examples sit at the same place; "
                                  "remove the duplicate or add smoothing", ErrorCode.SINGULAR)
    if P.shape[1] and np.linalg.matrix_rank(P) < P.shape[1]:
        raise ShapeSpaceError(f"the examples cannot determine a degree-{degree} polynomial (they are "
                              "collinear/coplanar); lower the degree", ErrorCode.SINGULAR)


def fit_rbf(centers: ArrayLike, values: ArrayLike | None = None, kernel: str = "thin_plate_spline",
            epsilon: float = 1.0, degree: int | None = None, smoothing: float = 0.0) -> RBFInterpolant:
    """Fit an RBF interpolant (thesis Eq. 8.4, with weight decay Eq. 8.3).

    Solves the block system ``[Φ + λI, P; Pᵀ, 0] [w; a] = [d; 0]`` with
    ``Φ_ij = φ(ε‖x_i − x_j‖)`` and ``P`` the monomials of the (centred and
    scaled) centres.

    Parameters
    ----------
    centers : array_like, shape (K, d)
        Example locations in pose space (a 1-D array is K points in 1-D).
    values : array_like, shape (K, ...), optional
        Data at the centres (any trailing shape, e.g. (K, p, 3) correctives);
        omit to use only :meth:`RBFInterpolant.cardinal`.
    kernel : str
        One of :data:`KERNELS`.
    epsilon : float
        Shape parameter: the kernel is evaluated at ``ε · distance``.
    degree : int, optional
        Polynomial degree, −1 for none.  Defaults to scipy's choice (the
        kernel's minimum, at least 0).  Must be at least the kernel's minimum.
    smoothing : float
        λ ≥ 0 added to the kernel matrix diagonal (0 interpolates exactly).

    Returns
    -------
    RBFInterpolant

    Raises
    ------
    ShapeSpaceError
        Bad shapes, unknown kernel, too few centres for the polynomial, or a
        singular system (duplicate centres without smoothing).
    """
    x = _points(centers, "centers")
    K, dim = x.shape
    if K < 1:
        raise ShapeSpaceError("an interpolant needs at least one centre", ErrorCode.TOO_FEW)
    if kernel not in KERNELS:
        raise ShapeSpaceError(f"unknown kernel {kernel!r}; choose from {', '.join(KERNELS)}", ErrorCode.KERNEL)
    epsilon = _epsilon(epsilon)
    if not (np.isfinite(smoothing) and smoothing >= 0):
        raise ShapeSpaceError(f"smoothing must be non-negative and finite, got {smoothing}", ErrorCode.RANGE)
    min_deg = KERNELS[kernel][1]
    degree = _default_degree(kernel) if degree is None else int(degree)
    if degree < min_deg:
        raise ShapeSpaceError(f"kernel {kernel!r} needs a polynomial of degree ≥ {min_deg}, got {degree}",
                              ErrorCode.DEGREE)
    powers = _monomial_powers(dim, degree)
    if K < powers.shape[0]:
        raise ShapeSpaceError(
            f"{K} examples are too few for a degree-{degree} polynomial in {dim} dimensions "
            f"(needs ≥ {powers.shape[0]}); lower the degree", ErrorCode.TOO_FEW)
    lo, hi = x.min(axis=0), x.max(axis=0)
    shift = (lo + hi) / 2.0
    scale = np.where(hi - lo > 0, (hi - lo) / 2.0, 1.0)
    phi = KERNELS[kernel][0](epsilon * pairwise_distances(x, x))
    P = _poly_matrix(x, shift, scale, powers)
    n_p = P.shape[1]
    A = np.zeros((K + n_p, K + n_p))
    A[:K, :K] = phi
    A[:K, :K][np.diag_indices(K)] += smoothing
    A[:K, K:] = P
    A[K:, :K] = P.T
    _check_solvable(x, P, degree, smoothing)
    try:
        lu = lu_factor(A, check_finite=False)
    except (ValueError, np.linalg.LinAlgError):
        lu = None
    if lu is None or not np.all(np.isfinite(lu[0])) or np.any(np.diag(lu[0]) == 0):
        raise ShapeSpaceError("the interpolation system is singular; add smoothing", ErrorCode.SINGULAR)
    interp = RBFInterpolant(x, kernel, epsilon, degree, float(smoothing), lu, shift, scale, powers)
    if values is not None:
        d = validate.array(values, "values")
        if d.ndim < 1 or d.shape[0] != K:
            raise ShapeSpaceError(f"values must have {K} rows (one per centre), got shape {d.shape}",
                                  ErrorCode.SHAPE)
        rhs = np.zeros((K + n_p, int(np.prod(d.shape[1:], dtype=int))))
        rhs[:K] = d.reshape(K, -1)
        interp._coeffs = lu_solve(lu, rhs).reshape((K + n_p,) + d.shape[1:])
    return interp


def loo_errors(centers: ArrayLike, values: ArrayLike, kernel: str = "gaussian", epsilon: float = 1.0,
               degree: int | None = None, smoothing: float = 0.0) -> np.ndarray:
    """Leave-one-out errors of an RBF fit in closed form (Rippa 1999).

    ``e_k = (A⁻¹ [d; 0])_k / (A⁻¹)_kk`` — the error at example k of the fit
    made without it, for every k at the cost of one factorisation of the
    Eq. 8.4 block matrix ``A``.

    Parameters
    ----------
    centers : array_like, shape (K, d)
    values : array_like, shape (K, ...)
    kernel, epsilon, degree, smoothing
        As :func:`fit_rbf`.

    Returns
    -------
    ndarray, shape (K, ...)
        ``values[k]`` minus the prediction at centre k of the fit to the other centres.
    """
    interp = fit_rbf(centers, values, kernel, epsilon, degree, smoothing)
    K = interp.n_centers
    n = interp._lu[0].shape[0]
    inv_diag = np.array([lu_solve(interp._lu, np.eye(n)[:, k])[k] for k in range(K)])
    coeffs = interp._coeffs.reshape(n, -1)[:K]
    return (coeffs / inv_diag[:, None]).reshape((K,) + interp._coeffs.shape[1:])


def choose_epsilon(centers: ArrayLike, values: ArrayLike, kernel: str = "gaussian", degree: int | None = None,
                   smoothing: float = 0.0, candidates: ArrayLike | None = None) -> tuple[float, np.ndarray]:
    """Kernel width by leave-one-out cross validation: the ε with the smallest LOO error norm.

    Parameters
    ----------
    centers : array_like, shape (K, d)
    values : array_like, shape (K, ...)
    kernel, degree, smoothing
        As :func:`fit_rbf`.
    candidates : array_like, shape (c,), optional
        Widths to try; default 25 values from 0.05 to 20 over the median
        distance between the centres.

    Returns
    -------
    epsilon : float
    scores : ndarray, shape (c,)
        RMS leave-one-out error per candidate (inf where the system was singular).
    """
    x = _points(centers, "centers")
    if candidates is None:
        d = pairwise_distances(x, x)
        typical = np.median(d[d > 0]) if np.any(d > 0) else 1.0
        candidates = np.geomspace(0.05, 20.0, 25) / typical
    scores = []
    for eps in candidates:
        try:
            e = loo_errors(x, values, kernel, eps, degree, smoothing)
            scores.append(float(np.sqrt(np.mean(e ** 2))))
        except ShapeSpaceError:
            scores.append(np.inf)
    scores = np.array(scores)
    if not np.isfinite(scores).any():
        raise ShapeSpaceError("no candidate kernel width gives a solvable system", ErrorCode.SINGULAR)
    return float(np.asarray(candidates)[int(np.argmin(scores))]), scores


@dataclass
class NormalizedRBF:
    """Normalised RBF: ``f(x) = Σ_k w_k φ_k(x) / Σ_j φ_j(x)``, exact at the examples (thesis ch. 8).

    The normalised kernel values form a partition of unity, so the cardinal
    weights sum to 1 everywhere.  Build with :func:`fit_normalized_rbf`.

    Attributes
    ----------
    centers : ndarray, shape (K, d)
    kernel : str
        One of :data:`POSITIVE_KERNELS`.
    epsilon : float
    """

    centers: np.ndarray
    kernel: str
    epsilon: float
    _lu: tuple

    def _phi_n(self, x):
        x = _points(x, "x", self.centers.shape[1])
        phi = KERNELS[self.kernel][0](self.epsilon * pairwise_distances(x, self.centers))
        total = phi.sum(axis=1, keepdims=True)
        return phi / np.where(np.abs(total) > 1e-300, total, 1e-300)

    def cardinal(self, x: ArrayLike) -> np.ndarray:
        """Cardinal weights at ``x`` (m, d), shape (m, K); rows sum to 1."""
        return lu_solve(self._lu, self._phi_n(x).T, trans=1).T


def fit_normalized_rbf(centers: ArrayLike, kernel: str = "gaussian", epsilon: float = 1.0) -> NormalizedRBF:
    """Fit a normalised RBF (the interpolant of Kurihara–Miyata's weighted PSD, thesis ch. 8).

    Parameters
    ----------
    centers : array_like, shape (K, d)
    kernel : str
        A positive kernel (:data:`POSITIVE_KERNELS`).
    epsilon : float
        Shape parameter, > 0.

    Returns
    -------
    NormalizedRBF

    Raises
    ------
    ShapeSpaceError
        Bad centres or width, a kernel that can change sign, or duplicate centres (singular system).
    """
    x = _points(centers, "centers")
    epsilon = _epsilon(epsilon)
    if kernel not in POSITIVE_KERNELS:
        raise ShapeSpaceError("normalised RBF needs a positive kernel (gaussian or inverse (multi)quadric)",
                              ErrorCode.KERNEL)
    model = NormalizedRBF(x, kernel, epsilon, None)
    A = model._phi_n(x)
    lu = lu_factor(A, check_finite=False)
    if np.min(np.abs(np.diag(lu[0]))) <= 1e-14 * np.abs(lu[0]).max():
        raise ShapeSpaceError("the normalised interpolation system is singular (duplicate examples?)",
                              ErrorCode.SINGULAR)
    model._lu = lu
    return model


@dataclass
class Shepard:
    """Shepard's inverse-distance weighting, ``c_k(x) ∝ ‖x − x_k‖^(−power)`` (exact at the examples).

    Attributes
    ----------
    centers : ndarray, shape (K, d)
    power : float
        Distance exponent, > 0 (2 by default).
    """

    centers: np.ndarray
    power: float = 2.0

    def __post_init__(self):
        self.centers = _points(self.centers, "centers")
        if self.centers.shape[0] < 1:
            raise ShapeSpaceError("Shepard interpolation needs at least one centre", ErrorCode.TOO_FEW)
        if not self.power > 0:
            raise ShapeSpaceError(f"power must be positive, got {self.power}", ErrorCode.RANGE)

    def cardinal(self, x: ArrayLike) -> np.ndarray:
        """Cardinal weights at ``x`` (m, d), shape (m, K); a query on a centre gets that centre's weight 1."""
        x = _points(x, "x", self.centers.shape[1])
        d = pairwise_distances(x, self.centers)
        out = np.zeros_like(d)
        hit = d <= 1e-12
        exact = hit.any(axis=1)
        out[exact] = hit[exact] / hit[exact].sum(axis=1, keepdims=True)
        inv = 1.0 / np.maximum(d[~exact], 1e-300) ** self.power
        out[~exact] = inv / inv.sum(axis=1, keepdims=True)
        return out


class SimplexLinear:
    """Linear interpolation on the Delaunay simplices of the examples (scipy.spatial).

    Outside the convex hull the nearest example's weight is 1 (constant
    extrapolation); 1-D pose spaces use sorted segments.

    Parameters
    ----------
    centers : array_like, shape (K, d)
        More than d examples, not all in one hyperplane (d > 1).
    """

    def __init__(self, centers: ArrayLike):
        x = _points(centers, "centers")
        if x.shape[0] < 1:
            raise ShapeSpaceError("linear interpolation needs at least one centre", ErrorCode.TOO_FEW)
        self.centers = x
        self._tree = cKDTree(x)
        if x.shape[1] == 1:
            self._order = np.argsort(x[:, 0])
            self._tri = None
        else:
            if x.shape[0] <= x.shape[1]:
                raise ShapeSpaceError(
                    f"linear interpolation on simplices needs more than {x.shape[1]} examples in {x.shape[1]}-D",
                    ErrorCode.TOO_FEW)
            try:
                self._tri = Delaunay(x)
            except Exception as exc:  # scipy's QhullError: degenerate (collinear / coplanar) examples
                raise ShapeSpaceError(f"the examples are degenerate in {x.shape[1]}-D (collinear or coplanar): "
                                      f"{str(exc).splitlines()[0]}", ErrorCode.DEGENERATE) from None

    def _cardinal_1d(self, x):
        K = self.centers.shape[0]
        out = np.zeros((x.shape[0], K))
        xs = self.centers[self._order, 0]
        for i, v in enumerate(x[:, 0]):
            j = np.searchsorted(xs, v)
            if j <= 0 or j >= K:
                out[i, self._order[0 if j <= 0 else K - 1]] = 1.0
            else:
                t = (v - xs[j - 1]) / (xs[j] - xs[j - 1])
                out[i, self._order[j - 1]] = 1.0 - t
                out[i, self._order[j]] = t
        return out

    def cardinal(self, x: ArrayLike) -> np.ndarray:
        """Cardinal weights at ``x`` (m, d), shape (m, K): barycentric coordinates in the enclosing simplex."""
        x = _points(x, "x", self.centers.shape[1])
        if self._tri is None:
            return self._cardinal_1d(x)
        out = np.zeros((x.shape[0], self.centers.shape[0]))
        simplex = self._tri.find_simplex(x)
        inside = simplex >= 0
        if inside.any():
            T = self._tri.transform[simplex[inside]]
            b = np.einsum("mij,mj->mi", T[:, :-1], x[inside] - T[:, -1])
            bary = np.hstack([b, 1.0 - b.sum(axis=1, keepdims=True)])
            verts = self._tri.simplices[simplex[inside]]
            rows = np.flatnonzero(inside)
            for c in range(verts.shape[1]):
                out[rows, verts[:, c]] += bary[:, c]
        if (~inside).any():
            _, nearest = self._tree.query(x[~inside])
            out[np.flatnonzero(~inside), nearest] = 1.0
        return out
