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
from ..boxqp import solve_box_qp
from ..progress import ProgressFn, notify
from ..validate import array

__all__ = ["fit_frames", "PROGRESS_FRAMES"]

#: Frames fitted between two progress reports.
PROGRESS_FRAMES = 64


def fit_frames(B: ArrayLike, neutral: ArrayLike, frames: ArrayLike, lo: ArrayLike, hi: ArrayLike,
               reg: float = 1e-6, *, progress: ProgressFn | None = None) -> np.ndarray:
    """Per-frame bounded least squares (lo ≤ w ≤ hi) of target sliders to source positions.

    Each frame f solves ``min ‖B w − (s_f − b0)‖² + reg·(tr(BᵀB)/n)·‖w‖²``.
    The regulariser is relative to the mean diagonal of ``BᵀB`` (so results do
    not depend on units) and floored at 1e-10 of it for a well-posed QP.  On a
    redundant rig (duplicate, scaled or empty keys: ``BᵀB`` singular) it picks
    the smallest-norm weights among the equal fits: exact duplicates share a
    motion equally, keys that move nothing stay at 0.  One eigendecomposition
    of ``BᵀB`` serves the whole take; each frame is one bounded solve
    (:func:`~core.boxqp.solve_box_qp`, projected Newton, a dense primal–dual
    active set when its ε-active set flips) warm-started from the previous
    frame's weights.  Only a frame that solver cannot finish is solved again
    with scipy's bounded least squares (BVLS; none on the shipped takes).

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
    x = np.clip(np.zeros(B.shape[1]), lo, hi)
    for f in range(rhs.shape[0]):
        if f % PROGRESS_FRAMES == 0:
            notify(progress, f / rhs.shape[0])
        g = B.T @ rhs[f]
        res = solve_box_qp(2 * a, V, 2 * s, 2 * g, lo, hi, x0=x)
        if res.status != 0 and res.residual > 1e-7 * max(1.0, 2 * float(np.abs(g).max())):
            x = _bvls(B, rhs[f], a, lo, hi)
        else:
            x = res.x
        out[f] = x


def _bvls(B: np.ndarray, r: np.ndarray, a: float, lo: ArrayLike, hi: ArrayLike) -> np.ndarray:
    """The same frame by scipy's bounded least squares on the ridge-augmented system ``[B; √a I]``."""
    from scipy.optimize import lsq_linear
    A = np.vstack([B, np.sqrt(a) * np.eye(B.shape[1])])
    b = np.concatenate([r, np.zeros(B.shape[1])])
    return lsq_linear(A, b, bounds=(lo, hi), method="bvls", tol=1e-12).x
