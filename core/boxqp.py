"""Bound-constrained convex quadratic programs with an identity-plus-low-rank Hessian.

Solves ``min_x ½ xᵀ H x − gᵀ x  subject to  lo ≤ x ≤ hi`` where
``H = a·I + V·diag(s)·Vᵀ`` is positive definite, ``V`` is ``n × r`` with
``r ≪ n``.  This is the shape of every direct-manipulation problem in
thesis ch. 4: the pin term ``RᵀR`` has rank ≤ 3k (k pins) and the
regularisers add a scaled identity (Eq. 4.5) or an identity minus a
low-rank prior correction (the learned modes, Eq. 4.8).

Method: projected Newton with an ε-active set (Bertsekas, 1982).  On the
free variables the Newton system is solved with the Woodbury identity, so
an iteration costs ``O(n r² + r³)``; bound variables take a scaled
projected-gradient step; an Armijo search along the projection arc makes it
globally convergent for any starting point, and once the active set is
identified the Newton step is exact (the objective is quadratic), so the
method terminates with the optimum.  Warm starts (the previous mouse-move's
solution) usually identify the active set at once.

Stopping test: the natural residual ``‖x − clip(x − ∇f(x))‖∞ ≤ tol ·
max(1, ‖g‖∞)``, which is zero exactly at the KKT point.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .result import ShapeSpaceError

__all__ = ["BoxQPResult", "solve_box_qp", "objective"]


@dataclass
class BoxQPResult:
    x: np.ndarray
    iterations: int
    status: int          # 0 converged, 1 iteration limit
    residual: float      # final natural residual (∞-norm)
    message: str


def _hess_apply(a, V, s, x):
    return a * x + V @ (s * (V.T @ x))


def objective(a, V, s, g, x) -> float:
    """``½ xᵀ H x − gᵀ x`` for ``H = a I + V diag(s) Vᵀ``."""
    return float(0.5 * x @ _hess_apply(a, V, s, x) - g @ x)


def _free_solve(a, Vf, s, rhs):
    """Solve ``(a I + Vf diag(s) Vfᵀ) d = rhs`` by Woodbury (Vf: free rows of V)."""
    if Vf.shape[1] == 0:
        return rhs / a
    inner = np.diag(a / s) + Vf.T @ Vf
    return (rhs - Vf @ np.linalg.solve(inner, Vf.T @ rhs)) / a


def solve_box_qp(a, V, s, g, lo, hi, x0=None, tol=1e-13, max_iter=200) -> BoxQPResult:
    """Minimise ``½ xᵀ(aI + V diag(s) Vᵀ)x − gᵀx`` over the box ``[lo, hi]``.

    Parameters
    ----------
    a : float
        Identity weight, > 0.
    V : ndarray, shape (n, r)
    s : ndarray, shape (r,)
        Nonzero; may be negative as long as ``H`` stays positive definite.
    g : ndarray, shape (n,)
    lo, hi : ndarray, shape (n,)
        Bounds with ``lo ≤ hi`` (``-inf``/``inf`` allowed).
    x0 : ndarray, shape (n,), optional
        Warm start; projected onto the box.
    tol : float
        Relative tolerance on the natural residual.
    max_iter : int

    Returns
    -------
    BoxQPResult
    """
    g = np.asarray(g, dtype=np.float64)
    n = g.shape[0]
    V = np.asarray(V, dtype=np.float64).reshape(n, -1)
    s = np.asarray(s, dtype=np.float64).reshape(-1)
    lo = np.asarray(lo, dtype=np.float64).reshape(n)
    hi = np.asarray(hi, dtype=np.float64).reshape(n)
    if not a > 0:
        raise ShapeSpaceError(f"a must be positive, got {a}", "shape")
    if V.shape[1] != s.shape[0]:
        raise ShapeSpaceError(f"V has {V.shape[1]} columns but s has {s.shape[0]} entries", "shape")
    if np.any(s == 0):
        raise ShapeSpaceError("s must have no zero entries (drop those columns of V)", "shape")
    if np.any(lo > hi):
        raise ShapeSpaceError("lo must not exceed hi", "range")
    x = np.clip(np.zeros(n) if x0 is None else np.asarray(x0, dtype=np.float64), lo, hi)
    scale = max(1.0, float(np.abs(g).max(initial=0.0)))
    sigma = 1e-4
    gram = V.T @ V                      # r × r, reused for every free-set solve
    vx = V.T @ x
    f = 0.5 * (a * (x @ x) + (s * vx) @ vx) - g @ x
    for it in range(1, max_iter + 1):
        grad = a * x + V @ (s * vx) - g
        res = float(np.abs(x - np.clip(x - grad, lo, hi)).max(initial=0.0))
        if res <= tol * scale:
            return BoxQPResult(x, it - 1, 0, res, "converged")
        eps = min(1e-3, res)
        active = ((x <= lo + eps) & (grad > 0)) | ((x >= hi - eps) & (grad < 0))
        d = -grad / a
        n_act = int(active.sum())
        if n_act < n:
            # Woodbury on the free block: (aI + Vf S Vfᵀ)⁻¹ q = (q − Vf (aS⁻¹ + VfᵀVf)⁻¹ Vfᵀ q) / a,
            # with VfᵀVf = VᵀV − VaᵀVa (cheaper when few variables are bound).
            Va = V[active]
            inner = gram - Va.T @ Va
            inner[np.diag_indices_from(inner)] += a / s
            qf = np.where(active, 0.0, grad)
            d_free = -(qf - V @ np.linalg.solve(inner, V.T @ qf)) / a
            d = np.where(active, d, d_free)
        free = ~active
        t = 1.0
        while True:
            xt = np.clip(x + t * d, lo, hi)
            vxt = V.T @ xt
            ft = 0.5 * (a * (xt @ xt) + (s * vxt) @ vxt) - g @ xt
            decrease = sigma * (-t * grad[free] @ d[free] + grad[active] @ (x[active] - xt[active]))
            if f - ft >= decrease or t < 1e-12:
                break
            t *= 0.5
        if ft > f:  # no progress possible in floating point: the optimum to rounding
            return BoxQPResult(x, it, 0, res, "converged (rounding limit)")
        x, f, vx = xt, ft, vxt
    grad = _hess_apply(a, V, s, x) - g
    res = float(np.abs(x - np.clip(x - grad, lo, hi)).max(initial=0.0))
    status = 0 if res <= tol * scale else 1
    return BoxQPResult(x, max_iter, status, res, "converged" if status == 0 else "iteration limit reached")
