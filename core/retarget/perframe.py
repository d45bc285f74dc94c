"""Per-frame fitting of target sliders to source geometry (thesis 3.5).

Each frame on its own: the bounded, ridge-regularised least-squares fit of
the target's delta matrix to the source positions at the corresponding
points.  The space-time method (:mod:`.spacetime_solver`) uses it for its default
end frames.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from ..blas_threads import single_threaded
from ..boxqp import active_set_dense, solve_box_qp
from ..progress import ProgressFn, notify
from ..validate import array

__all__ = ["fit_frames", "PROGRESS_FRAMES"]

#: Frames fitted between two progress reports.
PROGRESS_FRAMES = 64
#: Largest slider count solved with the dense active set (beyond: projected Newton on the eigen-factors).
DENSE_MAX = 512
#: Natural-residual tolerance of a frame's active-set solution, relative to ``max(1, ‖2Bᵀr‖∞)``.
FRAME_TOL = 1e-12


def fit_frames(B: ArrayLike, neutral: ArrayLike, frames: ArrayLike, lo: ArrayLike, hi: ArrayLike,
               reg: float = 1e-6, *, progress: ProgressFn | None = None) -> np.ndarray:
    """Per-frame bounded least squares (lo ≤ w ≤ hi) of target sliders to source positions.

    Each frame f solves ``min ‖B w − (s_f − b0)‖² + reg·(tr(BᵀB)/n)·‖w‖²``.
    The regulariser is relative to the mean diagonal of ``BᵀB`` (so results do
    not depend on units) and floored at 1e-10 of it for a well-posed QP.  On a
    redundant rig (duplicate, scaled or empty keys: ``BᵀB`` singular) it picks
    the smallest-norm weights among the equal fits: exact duplicates share a
    motion equally, keys that move nothing stay at 0.  One eigendecomposition
    of ``BᵀB`` (and, up to :data:`DENSE_MAX` sliders, the Hessian ``2(BᵀB + a I)``)
    serves the whole take; each frame is one exact primal–dual active-set solve
    (:func:`~core.boxqp.active_set_dense`) started from the previous frame's
    held sets — one or two Cholesky solves of the free block per frame, also
    on a redundant rig where the projected Newton method of
    :func:`~core.boxqp.solve_box_qp` crawls (tiny eigenvalues: 500 iterations
    per frame on a 124-key rig).  A frame whose sets cycle falls back to
    :func:`~core.boxqp.solve_box_qp`, then to scipy's bounded least squares
    (BVLS); none do on the shipped takes.

    Parameters
    ----------
    B : ndarray (3m, n)
        Target delta-matrix rows at the corresponding points.
    neutral : ndarray (3m,)
    frames : ndarray (f, 3m)
        Source positions at the corresponding points, per frame.
    lo, hi : ndarray (n,)
        Slider bounds (may be infinite).
    reg : float
        Ridge, relative to ``tr(BᵀB)/n``.
    progress : callable, optional
        ``progress(fraction)`` every :data:`PROGRESS_FRAMES` frames (:mod:`core.progress`); raising
        :class:`~core.progress.Cancelled` from it stops the fit.

    Returns
    -------
    ndarray (f, n)
        The fitted weights, each frame warm-started from the previous one.
    """
    B = array(B, "B", ndim=2)
    S = array(frames, "frames", shape=(None, B.shape[0]))
    rhs = S - array(neutral, "neutral", shape=(B.shape[0],))
    G = B.T @ B
    scale = max(np.trace(G) / G.shape[0], 1e-300)
    a = max(reg, 1e-10) * scale
    lam, Q = np.linalg.eigh(G)
    keep = lam > 1e-12 * lam.max()
    V, s = Q[:, keep], lam[keep]
    out = np.empty((S.shape[0], B.shape[1]))
    with single_threaded():                  # one small solve per frame: BLAS threads only spin (core.blas_threads)
        _fit_loop(B, rhs, a, V, s, lo, hi, out, progress)
    notify(progress, 1.0)
    return out


def _fit_loop(B: np.ndarray, rhs: np.ndarray, a: float, V: np.ndarray, s: np.ndarray, lo: ArrayLike,
              hi: ArrayLike, out: np.ndarray, progress: ProgressFn | None) -> None:
    """The frames of :func:`fit_frames`, each warm-started from the previous one, into ``out`` (f, n)."""
    n = B.shape[1]
    lo, hi = np.broadcast_to(np.asarray(lo, dtype=np.float64), (n,)), np.broadcast_to(np.asarray(hi, float), (n,))
    H = 2.0 * (a * np.eye(n) + (V * s) @ V.T) if n <= DENSE_MAX else None
    x = np.clip(np.zeros(n), lo, hi)
    lower = upper = np.zeros(n, dtype=bool)
    for f in range(rhs.shape[0]):
        if f % PROGRESS_FRAMES == 0:
            notify(progress, f / rhs.shape[0])
        g = 2.0 * (B.T @ rhs[f])
        x = _frame(H, a, V, s, g, B, rhs[f], lo, hi, x, lower, upper)
        grad = (2.0 * a) * x + V @ (2.0 * s * (V.T @ x)) - g
        lower, upper = (x <= lo) & (grad > 0), (x >= hi) & (grad < 0)
        out[f] = x


def _frame(H, a, V, s, g, B, r, lo, hi, x, lower, upper) -> np.ndarray:
    """One frame: the dense active set from the previous frame's held sets, checked by its natural residual;
    else projected Newton from the previous weights; else BVLS.  Within ``[lo, hi]`` exactly."""
    scale = max(1.0, float(np.abs(g).max()))
    if H is not None:
        xp, _ = active_set_dense(H, g, lo, hi, x, lower, upper)
        if xp is not None and float(np.abs(xp - np.clip(xp - (H @ xp - g), lo, hi)).max()) <= FRAME_TOL * scale:
            return xp
    res = solve_box_qp(2 * a, V, 2 * s, g, lo, hi, x0=x)
    if res.status != 0 and res.residual > 1e-7 * scale:
        return np.clip(_bvls(B, r, a, lo, hi), lo, hi)
    return np.clip(res.x, lo, hi)


def _bvls(B: np.ndarray, r: np.ndarray, a: float, lo: ArrayLike, hi: ArrayLike) -> np.ndarray:
    """The same frame by scipy's bounded least squares on the ridge-augmented system ``[B; √a I]``."""
    from scipy.optimize import lsq_linear
    A = np.vstack([B, np.sqrt(a) * np.eye(B.shape[1])])
    b = np.concatenate([r, np.zeros(B.shape[1])])
    return lsq_linear(A, b, bounds=(lo, hi), method="bvls", tol=1e-12).x
