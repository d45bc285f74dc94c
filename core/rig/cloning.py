"""The cloning-matrix route onto any rig's controls for weight sources (issue #25, item 3; thesis ch. 5).

A source that gives expression weights (ARKit names: Live Link Face, Face Cap, a shape-key action) is a linear
combination of ``k`` source expressions.  The route solves once, per source expression, the controls that best
reproduce that expression on the target (:func:`expression_controls`: the expression's surface at weight 1 —
the face's own shape key, or the source key carried over by model transfer or landmarks — is the target of a
bounded regularised solve from the rest controls, :func:`core.rig.solve.solve_controls`).  The rows ``X`` (k, n)
are the cloning matrix; a frame with weights ``w`` (k,) maps linearly to::

    c(w) = r + (X − r)ᵀ w,   clipped into the bounds            (:func:`clone_controls`)

(``r`` the rest controls) — exact on a rig linear in its controls whose expressions it can reach, the start of a
geometric fit otherwise: each frame is then refined by a few warm-started Gauss–Newton steps toward the frame's
target surface (:func:`solve_take_cloning`, :func:`core.rig.take.solve_take` started from ``c(w_f)``, the
Jacobian carried from frame to frame).  A frame whose refinement reaches its step limit is ``NOT_CONVERGED``
(its value is the best controls found) and so is the take, as on the per-frame route.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ErrorCode
from ..progress import ProgressFn, notify, scaled
from ..result import Result, ShapeSpaceError, Status
from .solve import finite_difference_jacobian, solve_controls
from .take import RigTakeResult, solve_take

__all__ = ["CloningMatrix", "REFINE_STEPS", "clone_controls", "expression_controls", "solve_take_cloning"]

#: Gauss–Newton steps of the geometric refinement of each frame by default.
REFINE_STEPS = 5


@dataclass(kw_only=True)
class CloningMatrix(Result):
    """Per source expression, the controls reproducing it (``value`` (k, n), also :attr:`matrix`).

    Attributes
    ----------
    rest : ndarray (n,)
        The controls the map starts from (weights 0).
    expression_status : ndarray of int (k,)
        Each expression's solve status.
    expression_rms : ndarray (k,)
        RMS point distance of each expression as the rig reproduces it.
    """

    rest: np.ndarray = None
    expression_status: np.ndarray = None
    expression_rms: np.ndarray = None

    @property
    def matrix(self) -> np.ndarray:
        return self.value


def expression_controls(evaluate: Callable, rest: ArrayLike, expressions: ArrayLike, *,
                        lo: ArrayLike | None = None, hi: ArrayLike | None = None, scale: ArrayLike | None = None,
                        jacobian: Callable | None = None, steps: ArrayLike | None = None, reg: float = 1e-6,
                        pin_tol: float = 0.0, xtol: float = 0.0, max_iter: int = 50,
                        progress: ProgressFn | None = None) -> CloningMatrix:
    """The cloning matrix (module doc): each expression solved from ``rest``.

    Parameters
    ----------
    evaluate : callable (n,) -> (p, 3)
    rest : array_like (n,)
        Rest controls (inside the bounds); the ridge pulls toward them.
    expressions : array_like (k, p, 3)
        Each source expression's target positions at weight 1.
    lo, hi, scale, jacobian, steps, pin_tol, xtol, max_iter
        As in :func:`~core.rig.solve.solve_controls`.
    reg : float
        Ridge weight relative to ``tr(J₀ᵀJ₀)/n`` per squared natural unit (as :func:`core.rig.take.solve_take`).
    progress : callable, optional
        ``progress(fraction)`` per expression; :class:`~core.progress.Cancelled` stops it.

    Returns
    -------
    CloningMatrix
    """
    X = np.asarray(expressions, dtype=np.float64)
    r = np.array(rest, dtype=np.float64).reshape(-1)
    n = r.size
    if X.ndim != 3 or X.shape[2] != 3 or X.shape[0] == 0:
        raise ShapeSpaceError(f"expressions: expected (k, points, 3), got {X.shape}", ErrorCode.SHAPE)
    if not np.isfinite(X).all():
        raise ShapeSpaceError("expressions: not finite", ErrorCode.NON_FINITE)
    if not (np.isfinite(reg) and reg >= 0):
        raise ShapeSpaceError(f"reg = {reg} must be a non-negative number", ErrorCode.RANGE)
    s = np.ones(n) if scale is None else np.asarray(scale, dtype=np.float64).reshape(-1)
    lo_ = np.full(n, -np.inf) if lo is None else np.asarray(lo, dtype=np.float64)
    hi_ = np.full(n, np.inf) if hi is None else np.asarray(hi, dtype=np.float64)
    h = 1e-3 / s if steps is None else np.asarray(steps, dtype=np.float64)
    P0 = np.asarray(evaluate(r), dtype=np.float64)
    J0 = (np.asarray(jacobian(r, P0), dtype=np.float64) if jacobian is not None
          else finite_difference_jacobian(evaluate, r, h, lo_, hi_, base=P0))
    unit = float(np.einsum("ij,ij->", J0, J0)) / n / float(np.mean(s * s))
    k = X.shape[0]
    out, status, rms = np.empty((k, n)), np.empty(k, dtype=np.int64), np.empty(k)
    evals = 0
    for e in range(k):
        notify(progress, e / k)
        res = solve_controls(evaluate, r, X[e], lo=lo, hi=hi, scale=s, jacobian=jacobian, steps=steps,
                             reference=r, mu=reg * unit, pin_tol=pin_tol, xtol=xtol, max_iter=max_iter,
                             first_jacobian=J0.copy(), first_points=P0)
        out[e], status[e] = res.x, int(res.status)
        rms[e] = float(np.sqrt(np.mean(res.pin_errors ** 2)))
        evals += res.evaluations
    notify(progress, 1.0)
    bad = np.flatnonzero(status != Status.OK)
    return CloningMatrix(out, status=Status.NOT_CONVERGED if bad.size else Status.OK,
                         message=(f"{bad.size} of {k} expressions did not converge" if bad.size
                                  else f"{k} expressions solved"),
                         rest=r, expression_status=status, expression_rms=rms,
                         diagnostics={"evaluations": evals + 1 + (0 if jacobian is not None else n)})


def clone_controls(matrix: CloningMatrix, weights: ArrayLike, lo: ArrayLike | None = None,
                   hi: ArrayLike | None = None) -> np.ndarray:
    """``r + W (X − r)`` (F, n) for weights ``W`` (F, k), clipped into ``lo``/``hi`` (module doc)."""
    W = np.asarray(weights, dtype=np.float64)
    X, r = matrix.value, matrix.rest
    if W.ndim != 2 or W.shape[1] != X.shape[0]:
        raise ShapeSpaceError(f"weights: expected (frames, {X.shape[0]}), got {W.shape}", ErrorCode.SHAPE)
    if not np.isfinite(W).all():
        raise ShapeSpaceError("weights: not finite", ErrorCode.NON_FINITE)
    C = r + W @ (X - r)
    return np.clip(C, -np.inf if lo is None else lo, np.inf if hi is None else hi)


def solve_take_cloning(evaluate: Callable, rest: ArrayLike, expressions: ArrayLike, weights: ArrayLike,
                       targets: ArrayLike, *, lo: ArrayLike | None = None, hi: ArrayLike | None = None,
                       scale: ArrayLike | None = None, jacobian: Callable | None = None,
                       steps: ArrayLike | None = None, reg: float = 1e-6, pin_tol: float = 0.0, xtol: float = 0.0,
                       refine_steps: int = REFINE_STEPS, keep_linearisation: bool = False,
                       progress: ProgressFn | None = None) -> RigTakeResult:
    """A take by the cloning matrix then the geometric refinement (module doc).

    Parameters
    ----------
    evaluate, rest, expressions, lo, hi, scale, jacobian, steps, reg, pin_tol, xtol
        As in :func:`expression_controls`.
    weights : array_like (F, k)
        The source's weights per frame.
    targets : array_like (F, p, 3)
        The target surface of each frame (the geometric fit's targets).
    refine_steps : int
        Trial steps of each frame's refinement (≥ 1).
    keep_linearisation : bool
        As in :func:`core.rig.take.solve_take`.
    progress : callable, optional

    Returns
    -------
    RigTakeResult
        ``diagnostics`` also holds ``cloning_matrix`` (k, n), ``expression_rms`` (k,), ``cloned`` (F, n) — the
        linear map's controls before refinement — and ``expression_status``.
    """
    if int(refine_steps) < 1:
        raise ShapeSpaceError(f"refine_steps = {refine_steps} must be at least 1", ErrorCode.RANGE)
    M = expression_controls(evaluate, rest, expressions, lo=lo, hi=hi, scale=scale, jacobian=jacobian,
                            steps=steps, reg=reg, pin_tol=pin_tol, xtol=xtol, progress=scaled(progress, 0.0, 0.3))
    C = clone_controls(M, weights, lo, hi)
    res = solve_take(evaluate, C[0], targets, lo=lo, hi=hi, scale=scale, jacobian=jacobian, steps=steps,
                     rest=M.rest, reg=reg, pin_tol=pin_tol, xtol=xtol, max_iter=int(refine_steps), starts=C,
                     keep_linearisation=keep_linearisation, progress=scaled(progress, 0.3, 1.0))
    res.evaluations += M.diagnostics["evaluations"]
    res.diagnostics.update(method="cloning", cloning_matrix=M.value, expression_rms=M.expression_rms, cloned=C,
                           expression_status=M.expression_status)
    return res
