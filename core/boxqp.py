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
max(1, ‖g‖∞)``, which is zero exactly at the KKT point; or, when no step
decreases the objective measurably any more (the rounding limit of an
ill-conditioned problem), a residual ≤ 1e-8 · max(1, ‖g‖∞).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .result import ShapeSpaceError

__all__ = ["BoxQPResult", "DualLSQResult", "solve_box_qp", "solve_box_lsq_dual", "objective"]


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


def solve_box_qp(a, V, s, g, lo, hi, x0=None, tol=1e-13, max_iter=500) -> BoxQPResult:
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
    V = np.asarray(V, dtype=np.float64)
    if V.ndim == 1:
        V = V.reshape(n, 1)
    if V.ndim != 2 or V.shape[0] != n:
        raise ShapeSpaceError(f"V must have shape ({n}, r), got {V.shape}", "shape")
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
    dense = V.shape[1] >= n             # low rank buys nothing: solve the free block directly
    H = a * np.eye(n) + (V * s) @ V.T if dense else None
    gram = None if dense else V.T @ V   # r × r, reused for every free-set solve
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
        if n_act < n and dense:
            free_idx = np.flatnonzero(~active)
            d = d.copy()
            d[free_idx] = -np.linalg.solve(H[np.ix_(free_idx, free_idx)], grad[free_idx])
        elif n_act < n:
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
        if f - ft <= 4 * np.finfo(float).eps * max(abs(f), 1e-300):
            # no measurable decrease: at the optimum to rounding, or stalled
            if res <= 1e-8 * scale:
                return BoxQPResult(x if ft > f else xt, it, 0, res, "converged (rounding limit)")
            return BoxQPResult(x, it, 1, res, "stalled: no decrease possible")
        x, f, vx = xt, ft, vxt
    grad = _hess_apply(a, V, s, x) - g
    res = float(np.abs(x - np.clip(x - grad, lo, hi)).max(initial=0.0))
    status = 0 if res <= tol * scale else 1
    return BoxQPResult(x, max_iter, status, res, "converged" if status == 0 else "iteration limit reached")


@dataclass
class DualLSQResult:
    x: np.ndarray
    dual: np.ndarray
    iterations: int
    status: int          # 0 converged, 1 iteration limit
    gap: float           # final duality gap, relative to the primal objective
    message: str


def solve_box_lsq_dual(R, m, c, b, lo, hi, dual0=None, tol=1e-14, max_iter=100) -> DualLSQResult:
    """``min_x ‖R x − m‖² + c‖x − b‖²`` over the box ``[lo, hi]``, through its small dual.

    The Hessian is ``c·I + RᵀR`` with ``R`` of size ``q × n`` (``q = 3k`` rows
    for k pins, ``q ≪ n``).  Dualising ``r = R x − m`` gives a strongly
    concave problem in ``λ ∈ R^q``::

        d(λ) = −‖λ‖²/4 − λᵀm + c‖x(λ) − b‖² + λᵀR x(λ),
        x(λ) = clip(b − Rᵀλ / (2c), lo, hi),   ∇d(λ) = R x(λ) − m − λ/2.

    ``∇d`` is piecewise linear, so a semismooth Newton method with the
    generalised Hessian ``−(½ I + R_F R_Fᵀ / (2c))`` (``F`` = unclipped
    coordinates) and an Armijo search on ``d`` converges globally (strong
    concavity, modulus ½) and, once the clipping pattern is right, in one
    exact step.  Stopping test: the duality gap ``J(x(λ)) − d(λ) ≤ tol·J``;
    at ``∇d = 0`` the gap is zero and ``x(λ)`` is the exact minimiser.

    Parameters
    ----------
    R : ndarray, shape (q, n)
    m : ndarray, shape (q,)
    c : float
        Positive.
    b : ndarray, shape (n,)
    lo, hi : ndarray, shape (n,)
    dual0 : ndarray, shape (q,), optional
        Warm start (e.g. ``2 (R x_prev − m)``).

    Returns
    -------
    DualLSQResult
    """
    R = np.asarray(R, dtype=np.float64)
    q, n = R.shape
    m = np.asarray(m, dtype=np.float64).reshape(q)
    b = np.asarray(b, dtype=np.float64).reshape(n)
    if not c > 0:
        raise ShapeSpaceError(f"c must be positive, got {c}", "shape")
    lam = np.zeros(q) if dual0 is None else np.asarray(dual0, dtype=np.float64).reshape(q).copy()
    gram = R @ R.T

    def parts(lam):
        x = np.clip(b - (R.T @ lam) / (2 * c), lo, hi)
        rx = R @ x
        dx = x - b
        d = -0.25 * lam @ lam - lam @ m + c * (dx @ dx) + lam @ rx
        return x, rx, d

    x, rx, d = parts(lam)
    gap = np.inf
    H = None
    free_prev = None
    for it in range(max_iter + 1):
        res = rx - m
        primal = res @ res + c * ((x - b) @ (x - b))
        gap = primal - d
        if gap <= tol * max(primal, 1e-300):
            return DualLSQResult(x, lam, it, 0, gap / max(primal, 1e-300), "converged")
        if it == max_iter:
            break
        grad = res - 0.5 * lam
        free = (x > lo) & (x < hi)
        if H is None or it % 10 == 0:
            # H = ½I + R_F R_Fᵀ/(2c), built from whichever of the free/bound column sets is smaller
            if 2 * free.sum() <= n:
                Rf = R[:, free]
                H = Rf @ Rf.T
            else:
                Rb = R[:, ~free]
                H = gram - Rb @ Rb.T if Rb.shape[1] else gram.copy()
            H /= 2 * c
            H.flat[::q + 1] += 0.5
        else:
            # the free set changes in a few coordinates between iterations: rank updates
            entered = free & ~free_prev
            left = free_prev & ~free
            if entered.any():
                Re = R[:, entered]
                H += Re @ Re.T / (2 * c)
            if left.any():
                Rl = R[:, left]
                H -= Rl @ Rl.T / (2 * c)
        free_prev = free
        step = np.linalg.solve(H, grad)
        t, slope = 1.0, grad @ step
        while True:
            lam_t = lam + t * step
            x_t, rx_t, d_t = parts(lam_t)
            if d_t >= d + 1e-4 * t * slope or t < 1e-12:
                break
            t *= 0.5
        if d_t < d:  # no ascent possible in floating point: optimal to rounding
            return DualLSQResult(x, lam, it, 0, gap / max(primal, 1e-300), "converged (rounding limit)")
        lam, x, rx, d = lam_t, x_t, rx_t, d_t
    status = 0 if gap <= 1e-10 * max(primal, 1e-300) else 1
    return DualLSQResult(x, lam, max_iter, status, gap / max(primal, 1e-300),
                         "converged" if status == 0 else "iteration limit reached")
