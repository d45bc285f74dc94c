"""Per-frame solvers, precomputed once so that one frame costs a matrix-vector product or a small QP.

The offline retarget methods (thesis 3.5, ch. 5) made per packet:

- :class:`CopySolver` — corresponding parameterisation, ``x_j = clip(g_j w_i + o_j, lo_j, hi_j)`` for each
  mapped pair ``(i, j)`` (unmapped targets 0), the offline ``copy``;
- :class:`LearnedSolver` — linear expression cloning ``x = clip(w_M E, lo, hi)`` with ``E`` learned offline
  from key poses on the moving source channels ``M``, the offline ``learned``;
- :class:`GeometricSolver` — the bounded geometric fit through a source template rig: the source weights
  pose the template (a copy onto its sliders), its motion is carried onto the target's vertices by a
  fixed linear map ``T`` (landmark correspondence, 3.5.4), and the target's sliders solve
  ``min ‖B x − T w_T‖² + a‖x‖²`` over ``lo ≤ x ≤ hi`` with ``a = reg · tr(BᵀB)/n`` — the offline
  ``perframe`` fit.  ``K = BᵀT`` and the eigen-decomposition of ``G = BᵀB`` are computed once; a frame is
  ``g = K w_T`` and a warm-started bounded QP in the n target sliders (:func:`dense_box_qp`: the projected
  Newton method of :mod:`core.boxqp` for a fixed dense Hessian, its free-block systems solved by Cholesky
  through SciPy's LAPACK), falling back to bounded least squares on the Cholesky factor of ``aI + G`` if the
  QP cannot finish.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ErrorCode
from ..result import ShapeSpaceError
from ..validate import array

__all__ = ["CopySolver", "LearnedSolver", "GeometricSolver", "dense_box_qp"]


def _bounds(lo: ArrayLike, hi: ArrayLike, n: int) -> tuple:
    lo = array(lo, "lo", shape=(n,), finite=False)
    hi = array(hi, "hi", shape=(n,), finite=False)
    if np.isnan(lo).any() or np.isnan(hi).any() or np.any(lo > hi):
        raise ShapeSpaceError("slider bounds must satisfy lo ≤ hi (no NaN)", ErrorCode.INFEASIBLE)
    return lo, hi


def dense_box_qp(H: np.ndarray, g: np.ndarray, lo: np.ndarray, hi: np.ndarray, x0: np.ndarray,
                 tol: float = 1e-13, max_iter: int = 200) -> tuple:
    """``min ½ xᵀHx − gᵀx`` over ``lo ≤ x ≤ hi`` for a small dense positive definite ``H`` (n ≲ 200).

    Projected Newton with an ε-active set (Bertsekas 1982), as :func:`core.boxqp.solve_box_qp`: Newton on
    the free variables (Cholesky of ``H_FF``), a diagonally scaled gradient step on the bound ones, Armijo
    search along the projection arc.  Warm-started from ``x0``, a frame whose active set is unchanged
    finishes in one step.  No input checks: the caller (:class:`GeometricSolver`) validated everything once.

    Parameters
    ----------
    H : ndarray (n, n)
    g : ndarray (n,)
    lo, hi : ndarray (n,)
    x0 : ndarray (n,)
    tol : float
        On the natural residual ``‖x − clip(x − ∇f)‖∞``, relative to ``max(1, ‖g‖∞)``.
    max_iter : int

    Returns
    -------
    x : ndarray (n,)
    converged : bool
    iterations : int
    """
    from scipy.linalg import cho_factor, cho_solve
    x = np.clip(x0, lo, hi)
    diag = np.diag(H)
    scale = max(1.0, float(np.abs(g).max(initial=0.0)))
    Hx = H @ x
    f = 0.5 * (x @ Hx) - g @ x
    for it in range(max_iter):
        grad = Hx - g
        res = float(np.abs(x - np.clip(x - grad, lo, hi)).max(initial=0.0))
        if res <= tol * scale:
            return x, True, it
        eps = min(1e-3, res)
        active = ((x <= lo + eps) & (grad > 0)) | ((x >= hi - eps) & (grad < 0))
        d = -grad / diag
        free = np.flatnonzero(~active)
        if free.size:
            d[free] = -cho_solve(cho_factor(H[np.ix_(free, free)], check_finite=False), grad[free],
                                 check_finite=False)
        t = 1.0
        while True:
            xt = np.clip(x + t * d, lo, hi)
            Hxt = H @ xt
            ft = 0.5 * (xt @ Hxt) - g @ xt
            step = xt - x
            decrease = 1e-4 * (-(grad[free] @ step[free]) - grad[active] @ step[active])
            if f - ft >= decrease or t < 1e-12:
                break
            t *= 0.5
        if f - ft <= 4 * np.finfo(float).eps * max(abs(f), 1e-300):
            return (x, res <= 1e-8 * scale, it + 1)
        x, f, Hx = xt, ft, Hxt
    res = float(np.abs(x - np.clip(x - (Hx - g), lo, hi)).max(initial=0.0))
    return x, res <= tol * scale, max_iter


class CopySolver:
    """Mapped channels copied with gain and offset, clipped to the target's slider ranges.

    Parameters
    ----------
    pairs : sequence of (source index, target index)
    gain, offset : ndarray (n_target,)
    lo, hi : ndarray (n_target,)
    n_source : int
    """

    def __init__(self, pairs: Sequence, gain: ArrayLike, offset: ArrayLike, lo: ArrayLike, hi: ArrayLike,
                 n_source: int) -> None:
        if not pairs:
            raise ShapeSpaceError("source and target share no mapped channels", ErrorCode.NO_MAPPING)
        self.lo, self.hi = _bounds(lo, hi, len(lo))
        n_target = self.lo.size
        self.gain = array(gain, "gain", shape=(n_target,))
        self.offset = array(offset, "offset", shape=(n_target,))
        src = np.array([i for i, _ in pairs], dtype=np.intp)
        dst = np.array([j for _, j in pairs], dtype=np.intp)
        if src.min() < 0 or src.max() >= n_source or dst.min() < 0 or dst.max() >= n_target:
            raise ShapeSpaceError(f"a mapped pair lies outside {n_source} source and {n_target} target channels",
                                  ErrorCode.RANGE)
        self.src, self.dst = src, dst
        self.n_source, self.n_target = int(n_source), n_target

    def solve(self, w: np.ndarray) -> np.ndarray:
        """Target sliders (n_target,) for source weights ``w`` (n_source,)."""
        out = np.zeros(self.n_target)
        out[self.dst] = self.gain[self.dst] * w[self.src] + self.offset[self.dst]
        return np.clip(out, self.lo, self.hi)


class LearnedSolver:
    """A learned cloning matrix applied per frame: ``x = clip(w[source_index] E, lo, hi)``.

    Parameters
    ----------
    source_index : sequence of int (m,)
        The live source channels feeding the rows of ``E`` (the moving channels it was learned from).
    matrix : ndarray (m, n_target)
    lo, hi : ndarray (n_target,)
    """

    def __init__(self, source_index: Sequence[int], matrix: ArrayLike, lo: ArrayLike, hi: ArrayLike) -> None:
        self.index = np.asarray(source_index, dtype=np.intp)
        self.matrix = array(matrix, "matrix", shape=(self.index.size, None))
        self.lo, self.hi = _bounds(lo, hi, self.matrix.shape[1])

    def solve(self, w: np.ndarray) -> np.ndarray:
        """Target sliders (n_target,) for source weights ``w``."""
        return np.clip(w[self.index] @ self.matrix, self.lo, self.hi)


class GeometricSolver:
    """The bounded per-frame geometric fit through a template rig, factorised once.

    Parameters
    ----------
    template : CopySolver
        Source weights → the template rig's sliders.
    basis : ndarray (3p, n)
        The target's delta matrix at its vertices (size-normalised units).
    transfer : ndarray (3p, n_T)
        The template's shapes carried onto the target's vertices (same units): the target-vertex motion
        of template weights ``w_T`` is ``transfer @ w_T``.
    lo, hi : ndarray (n,)
        The target's slider ranges.
    reg : float
        Ridge relative to ``tr(BᵀB)/n`` (floored at 1e-10), as the offline per-frame fit.
    """

    def __init__(self, template: CopySolver, basis: ArrayLike, transfer: ArrayLike, lo: ArrayLike,
                 hi: ArrayLike, reg: float = 1e-6) -> None:
        B = array(basis, "basis", ndim=2)
        T = array(transfer, "transfer", shape=(B.shape[0], template.n_target))
        self.template = template
        self.lo, self.hi = _bounds(lo, hi, B.shape[1])
        self.K = B.T @ T
        self._init_gram(B.T @ B, reg)

    @classmethod
    def from_normal_equations(cls, template: CopySolver, K: ArrayLike, gram: ArrayLike, lo: ArrayLike,
                              hi: ArrayLike, reg: float = 1e-6) -> "GeometricSolver":
        """Build from ``K = BᵀT`` (n, n_T) and ``G = BᵀB`` (n, n) directly."""
        self = cls.__new__(cls)
        self.template = template
        self.K = array(K, "K", shape=(None, template.n_target))
        self.lo, self.hi = _bounds(lo, hi, self.K.shape[0])
        self._init_gram(array(gram, "gram", shape=(self.K.shape[0], self.K.shape[0])), reg)
        return self

    def _init_gram(self, G: np.ndarray, reg: float) -> None:
        n = G.shape[0]
        scale = max(np.trace(G) / n, 1e-300)
        self.a = max(reg, 1e-10) * scale
        self.H = 2.0 * (G + self.a * np.eye(n))            # the offline fit's Hessian, 2(aI + BᵀB)
        self.chol = np.linalg.cholesky(G + self.a * np.eye(n))
        self.reset()

    def reset(self) -> None:
        """Forget the warm start (the next frame starts from the box's point nearest 0)."""
        self.x = np.clip(np.zeros(self.K.shape[0]), self.lo, self.hi)
        self.fallbacks = 0
        self.iterations = 0

    def solve(self, w: np.ndarray) -> np.ndarray:
        """Target sliders (n,) for source weights ``w``, warm-started from the previous frame."""
        g = self.K @ self.template.solve(w)
        x, converged, self.iterations = dense_box_qp(self.H, 2 * g, self.lo, self.hi, self.x)
        if converged:
            self.x = x
        else:
            self.x = self._bounded_lsq(g)
            self.fallbacks += 1
        return self.x.copy()

    def _bounded_lsq(self, g: np.ndarray) -> np.ndarray:
        """``min ‖Lᵀx − L⁻¹g‖²`` over the box (``LLᵀ = aI + G``): the same QP by bounded least squares."""
        from scipy.linalg import solve_triangular
        from scipy.optimize import lsq_linear
        rhs = solve_triangular(self.chol, g, lower=True)
        return lsq_linear(self.chol.T, rhs, bounds=(self.lo, self.hi), method="bvls", tol=1e-12).x
