"""The dispatcher: :func:`spacetime` validates the input, solves the unbounded problem and, with bounds, runs the
bounded methods in order (:func:`_solve_bounded`); :class:`SpacetimeResult` is what it returns.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ...blas_threads import single_threaded
from ...errors import ErrorCode
from ...progress import ProgressFn, notify, scaled
from ...result import Result, ShapeSpaceError
from ...validate import array, finite_scalar, positive
from ..perframe import fit_frames
from .bounded import active_set, clipped_solve, interior_point, peak_active_set, projected_newton, shallow_violation
from .kernels import block_fits
from .system import SpacetimeSystem

__all__ = ["spacetime", "SpacetimeResult", "DRIFT_BETA", "END_RIDGE", "DEGENERATE_RATIO"]

#: Default β of the retarget command's space-time method (position term, per frame²; #11).
DRIFT_BETA = 1e-3

#: Ridge of the default end frames' per-frame fits in the whitened variables w/σ (relative to tr(ΣBᵀBΣ)/n, as
#: the retarget command's λ): small enough that the ends are the least-squares fits to ~1e-7 of the weights on a
#: rig without ties, large enough to split ties (by σ²) to float precision.
END_RIDGE = 1e-7

#: A rig whose ``M`` has an eigenvalue at most this fraction of its largest is rank-deficient: bounded space-time
#: goes straight to the interior point.
DEGENERATE_RATIO = 1e-10


@dataclass(kw_only=True)
class SpacetimeResult(Result):
    """Weights of a space-time solve (``value``, alias :attr:`weights`, shape (f, n)).

    ``iterations`` counts the bounded solver's outer iterations (active-set
    plus projected-Newton; 0 without bounds).  ``status`` is ``OK`` when the
    natural residual met the tolerance (or stopped decreasing at rounding
    level), ``NOT_CONVERGED`` at the iteration limit or when it stalled.
    ``diagnostics``: ``modes`` (unbounded) or ``natural_residual``, ``solves``,
    ``active_set_iterations``, ``newton_iterations`` (bounded).
    """

    @property
    def weights(self) -> np.ndarray:
        """The weights (f, n), including the fixed first and last frames."""
        return self.value


# ------------------------------------------------------------------ entry point
def _assemble(Y: np.ndarray, sig: np.ndarray, first: np.ndarray, last: np.ndarray,
              lo: np.ndarray | None = None, hi: np.ndarray | None = None) -> np.ndarray:
    """Weights (f, n) from the whitened interior ``Y`` and the fixed ends, clipped to the bounds if given."""
    W = np.empty((Y.shape[0] + 2, Y.shape[1]))
    W[0], W[-1] = first, last
    W[1:-1] = Y * sig
    if lo is not None:  # undo the rounding of the whitened bounds (lo/σ)·σ
        np.clip(W, lo, hi, out=W)
    return W


def _solve_bounded(system: SpacetimeSystem, Y: np.ndarray, R0: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                   first: np.ndarray, last: np.ndarray, tol: float, max_iter: int,
                   max_exact_active: int, progress: ProgressFn | None = None) -> SpacetimeResult:
    """The bounded problem from the unbounded solution ``Y``.

    :func:`peak_active_set` first (a handful of exact block solves on real
    takes); if it cycles, or the rig is rank-deficient (smallest eigenvalue of
    ``M`` ≤ :data:`DEGENERATE_RATIO` × the largest), :func:`interior_point`
    (robust on degenerate, redundant rigs); if that fails too, the primal–dual active set and
    projected Newton of before.  The final :func:`projected_newton` call
    checks the natural residual of the point returned (and returns at once
    when it passes).
    """
    sig = system.sigma
    ylo = np.broadcast_to(lo / sig, Y.shape)
    yhi = np.broadcast_to(hi / sig, Y.shape)
    scale = max(1.0, float(np.abs(R0).max()))
    system.solves = 0
    peak_iterations = ipm_iterations = pdas_iterations = 0
    exact = block_fits(system)
    Ys, done, start = Y, False, None
    # a rank-deficient rig (duplicate keys: M singular) has many bounded ties only λ tells apart, on which active-set
    # iterations cycle; the interior point goes straight through them
    degenerate = float(system.mu.min()) <= DEGENERATE_RATIO * float(system.mu.max())
    clipped = exact and shallow_violation(Y, ylo, yhi)
    if clipped:                              # nothing really clips: hold every sliver, one solve (usually final)
        Yc, done, start = clipped_solve(system, Y, R0, ylo, yhi, tol, scale, scaled(progress, 0.0, 0.5))
        Ys = Yc if done else Y
    if exact and not degenerate and not done:  # the peak iteration goes on from the clipped solve's held sets
        Ys, peak_iterations, done = peak_active_set(system, Yc if start else Y, R0, ylo, yhi, tol, max_iter, scale,
                                                    scaled(progress, 0.0, 0.5), start)
    if not done and exact and bool(np.all(lo < hi)):
        Ys, ipm_iterations, done = interior_point(system, Y, R0, ylo, yhi, tol, max_iter, scale,
                                                  scaled(progress, 0.5, 0.9))
        done = True                          # projected Newton finishes from the interior point's answer
    if not done:
        Ys, pdas_iterations = active_set(system, np.clip(Y, ylo, yhi), R0, ylo, yhi, max_iter, scale,
                                         max_exact_active)
    notify(progress, 0.9)
    Ys, newton_iterations, status, message, nat = projected_newton(
        system, np.clip(Ys, ylo, yhi), R0, ylo, yhi, tol, max_iter, scale, max_exact_active)
    notify(progress, 1.0)
    return SpacetimeResult(_assemble(Ys, sig, first, last, lo, hi), status=status, message=message,
                           iterations=peak_iterations + ipm_iterations + pdas_iterations + newton_iterations,
                           diagnostics={"natural_residual": nat, "solves": system.solves,
                                        "clipped_solve": bool(clipped),
                                        "peak_iterations": peak_iterations,
                                        "interior_point_iterations": ipm_iterations,
                                        "active_set_iterations": pdas_iterations,
                                        "newton_iterations": newton_iterations})


def _end_frames(B: np.ndarray, b0: np.ndarray, S: np.ndarray, sig: np.ndarray, lo: np.ndarray,
                hi: np.ndarray) -> np.ndarray:
    """The default fixed end frames (2, n): the per-frame bounded fits of the first and last source frames
    (:func:`~.perframe.fit_frames`, ridge :data:`END_RIDGE`) in the interior's whitened variables ``w / σ``, so a tie
    between duplicate keys splits in proportion to ``σ²`` at the ends as in between (no jump at frame 1);
    on a rig without ties the ridge is negligible either way."""
    W = fit_frames(B * sig, b0, S[[0, -1]].astype(np.float64), lo / sig, hi / sig, reg=END_RIDGE) * sig
    return np.clip(W, lo, hi)              # (lo/σ)·σ can round past lo


def _bound(x: ArrayLike | None, name: str, n: int, default: float) -> np.ndarray:
    """A bound as (n,) float64: ``default`` when absent, a scalar broadcast to every slider."""
    if x is None:
        return np.full(n, default)
    b = array(x, name, ndim=(0, 1), finite=False)
    if b.ndim == 1 and b.size != n:
        raise ShapeSpaceError(f"{name} must have shape ({n},), got {b.shape}", ErrorCode.SHAPE)
    if np.isnan(b).any():
        raise ShapeSpaceError(f"{name} contains NaN", ErrorCode.NON_FINITE)
    return np.broadcast_to(b, (n,))


def _sliders(indices: np.ndarray, names: Sequence[str] | None) -> str:
    """Sliders named for a message (their indices when no names are given)."""
    idx = [int(i) for i in indices]
    if names is None or len(names) <= max(idx, default=-1):
        return str(idx)
    return ", ".join(names[i] for i in idx)


def _check(B: ArrayLike, neutral: ArrayLike, frames: ArrayLike, sigma: ArrayLike, lo: ArrayLike | None,
           hi: ArrayLike | None, tol: float, max_iter: int, names: Sequence[str] | None = None) -> tuple:
    """Validated inputs of :func:`spacetime`: B, b0, S (dtype kept, not copied), σ, lo, hi."""
    B = array(B, "B", ndim=2)
    b0 = array(neutral, "neutral", shape=(B.shape[0],))
    S = np.asarray(frames)                       # not copied: only S·B is needed (memory for long shots)
    if S.ndim != 2 or S.shape[1] != B.shape[0]:
        raise ShapeSpaceError(f"frames must have shape (f, {B.shape[0]}), got {S.shape}", ErrorCode.SHAPE)
    if S.shape[0] < 3:
        raise ShapeSpaceError(f"space-time cloning needs at least 3 frames, got {S.shape[0]}", "too_short")
    n = B.shape[1]
    sig = array(sigma, "sigma", finite=False)
    if sig.size != n:
        raise ShapeSpaceError(f"sigma must have {n} entries (one per slider), got {sig.size}", ErrorCode.SHAPE)
    sig = sig.reshape(n)
    if np.any(sig <= 0) or not np.isfinite(sig).all():
        raise ShapeSpaceError(f"sigma must be positive and finite for every slider (not for "
                              f"{_sliders(np.flatnonzero(~(sig > 0) | ~np.isfinite(sig)), names)})", "range")
    lo, hi = _bound(lo, "lo", n, -np.inf), _bound(hi, "hi", n, np.inf)
    if np.any(lo > hi):
        raise ShapeSpaceError(f"lo exceeds hi for sliders {_sliders(np.flatnonzero(lo > hi), names)}",
                              ErrorCode.INFEASIBLE)
    positive(tol, "tol")
    if int(max_iter) < 1:
        raise ShapeSpaceError(f"max_iter must be at least 1, got {max_iter}", ErrorCode.RANGE)
    return B, b0, S, sig, lo, hi


def spacetime(B: ArrayLike, neutral: ArrayLike, frames: ArrayLike, sigma: ArrayLike, lam: float = 1e-3,
              first: ArrayLike | None = None, last: ArrayLike | None = None, lo: ArrayLike | None = None,
              hi: ArrayLike | None = None, tol: float = 1e-8, max_iter: int = 100, relative: bool = False,
              max_exact_active: int = 1000, names: Sequence[str] | None = None,
              beta: float = 0.0, anchor: bool = False, *, progress: ProgressFn | None = None) -> SpacetimeResult:
    """Space-time expression cloning (thesis ch. 5), optionally with slider bounds.

    Minimises ``‖D (W Bᵀ − S)‖² + β ‖W Bᵀ − S‖² + λ Σ_f Σ_k (w_fk / σ_k)²`` over the interior
    frames, with ``W[0] = first`` and ``W[-1] = last`` fixed (default: the
    per-frame fits of the end frames in the variables ``w / σ``, :func:`_end_frames`), where
    ``S`` are the source positions at the corresponding points relative to the
    target neutral and ``D`` the temporal first difference; with ``lo``/``hi``
    subject to ``lo ≤ w ≤ hi``.  See the module docstring for the method.

    Parameters
    ----------
    B : ndarray (3m, n)
        Target delta-matrix rows at the corresponding points.
    neutral : ndarray (3m,)
    frames : ndarray (f, 3m)
        Source positions, f ≥ 3 (float32 is fine: multiplied in row chunks).
    sigma : ndarray (n,)
        Per-slider scale σ_k (e.g. standard deviations of training weights, 5.5).
    lam : float
        λ.
    first, last : ndarray (n,), optional
        Fixed end frames.
    lo, hi : ndarray (n,) or float, optional
        Slider bounds (either may be omitted or infinite); giving either makes the problem bounded.
    tol : float
        Natural-residual tolerance of the bounded solve, relative to ``max(1, ‖rhs‖∞)``.
    max_iter : int
        Iteration limit of each of the two bounded phases.
    relative : bool
        Read ``lam`` relative to the data: λ · mean eigenvalue of ``ΣBᵀBΣ``
        (unit-free; used by the retarget command).
    max_exact_active : int
        Largest active set for which a Newton step uses the capacitance
        system (cost O(m³) plus lookup tables of O(c²·f) for the c channels
        involved); larger ones use the banded Cholesky (or CG).
    names : sequence of str (n,), optional
        Slider names for the messages (indices otherwise).
    beta : float
        β ≥ 0, weight of the position term (per frame², relative to the
        velocity term).  0 is the thesis' pure velocity matching; a small β
        (e.g. :data:`DRIFT_BETA`) anchors long takes so that errors the
        regulariser lets into slow modes cannot integrate into drift, while
        clipped stretches shorter than about 1/√β frames keep their velocity
        shape (Fig. 3.9).  Each mode stays one tridiagonal system
        ``(μ_j (T + β I) + λ) z_j = r_j``.
    anchor : bool
        Regularise towards the per-frame ridge fit instead of towards zero:
        ``λ Σ_f Σ_k ((w_fk − w⁰_fk) / σ_k)²`` with ``W⁰ = argmin ‖W Bᵀ − S‖² + λ ‖W Σ⁻¹‖²``
        frame by frame.  Where nothing clips, ``W⁰`` (plus the velocity
        term's own minimiser, the same up to O(λ)) is the answer: no drift on
        long takes, which the zero-pulling regulariser causes in modes with
        ``μ_j ≲ λ f²``.  Where sliders clip the pull is as weak as before, so
        the velocity shape is kept (Fig. 3.9).  Used by the retarget command.
    progress : callable, optional
        ``progress(fraction)`` while the source is multiplied (per chunk of
        :data:`CHUNK_ROWS` frames) and after every bounded iteration
        (:mod:`core.progress`); raising :class:`~core.progress.Cancelled` from
        it stops the solve.

    Returns
    -------
    SpacetimeResult
        ``weights`` (f, n), within the bounds exactly; ``status`` ``OK`` or
        ``NOT_CONVERGED`` (iteration limit, stalled).
    """
    bounded = lo is not None or hi is not None
    B, b0, S, sig, lo, hi = _check(B, neutral, frames, sigma, lo, hi, tol, max_iter, names)
    lam = finite_scalar(lam, "lam")
    beta = finite_scalar(beta, "beta")
    if beta < 0:
        raise ShapeSpaceError(f"beta must be ≥ 0, got {beta}", "range")
    F, n = S.shape[0], B.shape[1]
    if first is None or last is None:
        ends = _end_frames(B, b0, S, sig, lo if bounded else np.full(n, -1e6), hi if bounded else np.full(n, 1e6))
        first = ends[0] if first is None else first
        last = ends[1] if last is None else last
    first, last = array(first, "first", shape=(n,)), array(last, "last", shape=(n,))
    system = SpacetimeSystem(B, sig, lam, F, relative, beta)
    R0 = system.rhs(S, b0, first, last, anchor, progress=scaled(progress, 0.0, 0.3 if bounded else 0.95))
    Y = system.solve(R0)
    if not bounded:
        notify(progress, 1.0)
        return SpacetimeResult(_assemble(Y, sig, first, last), diagnostics={"modes": n})
    with single_threaded():                  # thousands of small BLAS calls: threads only spin (core.blas_threads)
        return _solve_bounded(system, Y, R0, lo, hi, first, last, tol, max_iter, max_exact_active,
                              scaled(progress, 0.3, 1.0))
