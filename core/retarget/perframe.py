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
from ..boxqp import active_set_dense, solve_box_qp, spd_solve
from ..progress import ProgressFn, notify
from ..validate import array

__all__ = ["fit_frames", "batched_active_set", "PROGRESS_FRAMES", "BATCH_FRAMES"]

#: Frames fitted between two progress reports (the frame-by-frame route).
PROGRESS_FRAMES = 64
#: Most frames solved together by :func:`batched_active_set` (one progress report per batch; a take is split into
#: at least 16 batches of at least :data:`PROGRESS_FRAMES`).
BATCH_FRAMES = 4096
#: Iterations of :func:`batched_active_set`; a frame whose sets still change goes frame by frame.
BATCH_ITERATIONS = 30
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
    serves the whole take; the frames are solved together by the primal–dual
    active set (:func:`batched_active_set`: frames that hold the same sliders share one Cholesky
    factor of the free block, up to :data:`BATCH_FRAMES` at a time; 36,000 frames onto FBHead
    in 0.4 s of CPU, 2.3 s frame by frame), and each frame's answer is checked by its natural
    residual.  A frame that fails the check (or whose sets still change after
    :data:`BATCH_ITERATIONS`), and every frame beyond :data:`DENSE_MAX` sliders,
    is solved on its own from the previous frame: the exact dense active set
    (:func:`~core.boxqp.active_set_dense`) from its held sets — also on a redundant
    rig where the projected Newton method of :func:`~core.boxqp.solve_box_qp`
    crawls (tiny eigenvalues: 500 iterations per frame on a 124-key rig) — then
    :func:`~core.boxqp.solve_box_qp`, then scipy's bounded least squares
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
        The fitted weights, within ``[lo, hi]`` exactly.
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
    """The frames of :func:`fit_frames` into ``out`` (f, n): batched (:func:`batched_active_set`) up to
    :data:`DENSE_MAX` sliders, the frames it does not settle (and every frame beyond) one by one."""
    n = B.shape[1]
    lo, hi = np.broadcast_to(np.asarray(lo, dtype=np.float64), (n,)), np.broadcast_to(np.asarray(hi, float), (n,))
    H = 2.0 * (a * np.eye(n) + (V * s) @ V.T) if n <= DENSE_MAX else None
    todo = np.ones(rhs.shape[0], dtype=bool)
    if H is not None:
        size = int(np.clip(-(-rhs.shape[0] // 16), PROGRESS_FRAMES, BATCH_FRAMES))
        for start in range(0, rhs.shape[0], size):
            notify(progress, start / rhs.shape[0])
            stop = min(start + size, rhs.shape[0])
            G = 2.0 * (rhs[start:stop] @ B)
            out[start:stop], done = batched_active_set(H, G, lo, hi)
            todo[start:stop] = ~done
    x = np.clip(np.zeros(n), lo, hi)
    lower = upper = np.zeros(n, dtype=bool)
    for f in np.flatnonzero(todo):
        if H is None and f % PROGRESS_FRAMES == 0:
            notify(progress, f / rhs.shape[0])
        if f and not todo[f - 1]:                           # warm start from the batched answer before it
            x = out[f - 1]
            grad = H @ x - 2.0 * (B.T @ rhs[f - 1])
            lower, upper = (x <= lo) & (grad > 0), (x >= hi) & (grad < 0)
        g = 2.0 * (B.T @ rhs[f])
        x = _frame(H, a, V, s, g, B, rhs[f], lo, hi, x, lower, upper)
        grad = (2.0 * a) * x + V @ (2.0 * s * (V.T @ x)) - g
        lower, upper = (x <= lo) & (grad > 0), (x >= hi) & (grad < 0)
        out[f] = x


def _group_solve(H: np.ndarray, G: np.ndarray, lower: np.ndarray, upper: np.ndarray, lo: np.ndarray,
                 hi: np.ndarray) -> np.ndarray:
    """Each frame's minimiser with its held entries at their bounds: frames holding the same sliders share one
    Cholesky factor of ``H``'s free block (one LAPACK solve with a column per frame).  (k, n)."""
    X = np.where(upper, hi, np.where(lower, lo, 0.0))
    held = lower | upper
    if not held.any():
        return spd_solve(H, G.T).T
    keys = np.packbits(np.concatenate([lower, upper], axis=1), axis=1)
    _, inverse = np.unique(keys, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    order = np.argsort(inverse, kind="stable")
    cuts = np.flatnonzero(np.diff(inverse[order])) + 1
    for rows in np.split(order, cuts):
        free = ~held[rows[0]]
        fi, hd = np.flatnonzero(free), np.flatnonzero(~free)
        if not fi.size:
            continue
        r = G[np.ix_(rows, fi)]
        if hd.size:
            r -= X[np.ix_(rows, hd)] @ H[np.ix_(hd, fi)]
        X[np.ix_(rows, fi)] = spd_solve(H[np.ix_(fi, fi)], r.T).T
    return X


def batched_active_set(H: np.ndarray, G: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                       max_iter: int = BATCH_ITERATIONS) -> tuple:
    """The exact minimisers of ``½ xᵀHx − g_fᵀx`` on ``lo ≤ x ≤ hi`` for many frames at once.

    The primal–dual active set (Hintermüller–Ito–Kunisch, as :func:`~core.boxqp.active_set_dense`) run on
    every frame together from the unconstrained minimisers: each pass solves the free blocks of all frames
    still changing, one Cholesky factor per distinct held set (:func:`_group_solve`), and re-reads each
    frame's held sets from its multipliers' signs; a frame is done when its sets repeat (its KKT point) and
    its natural residual ``‖x − clip(x − (Hx − g))‖∞ ≤`` :data:`FRAME_TOL` ``· max(1, ‖g‖∞)``.

    Parameters
    ----------
    H : ndarray (n, n)
        Symmetric positive definite.
    G : ndarray (f, n)
        Each frame's linear term ``g_f``.
    lo, hi : ndarray (n,)
        Bounds (may be infinite).
    max_iter : int
        Passes; a frame whose sets still change after them is not done.

    Returns
    -------
    X : ndarray (f, n)
        Within ``[lo, hi]``; the frames not done hold their last iterate.
    done : ndarray of bool (f,)
        The frames whose minimiser ``X`` is (passed the test).
    """
    f, n = G.shape
    X = np.clip(np.zeros((f, n)), lo, hi)
    lower = np.zeros((f, n), dtype=bool)
    upper = np.zeros((f, n), dtype=bool)
    pending = np.arange(f)
    for _ in range(max_iter):
        if not pending.size:
            break
        lw, up, g = lower[pending], upper[pending], G[pending]
        held = lw | up
        xn = _group_solve(H, g, lw, up, lo, hi)
        mult = g - xn @ H                                           # −∇f (H symmetric)
        new_up = np.where(held, up & (mult > 0), xn > hi)
        new_lw = np.where(held, lw & (mult < 0), xn < lo)
        settled = ~((new_up != up).any(axis=1) | (new_lw != lw).any(axis=1))
        X[pending[settled]] = np.clip(xn[settled], lo, hi)
        lower[pending], upper[pending] = new_lw, new_up
        pending = pending[~settled]
    done = np.ones(f, dtype=bool)
    done[pending] = False
    scale = np.maximum(1.0, np.abs(G).max(axis=1, initial=0.0))
    natural = np.abs(X - np.clip(X - (X @ H - G), lo, hi)).max(axis=1, initial=0.0)
    return X, done & (natural <= FRAME_TOL * scale)


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
