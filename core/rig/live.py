"""Live solve-through onto any rig (issue #25, item 4): one warm-started, budgeted bounded step per frame.

Each live frame gives target surface points ``t`` (p, 3) (the capture's weights played through the face's own
shape keys, thesis Eq. 3.1); the controls ``c`` (n,) of the rig are moved toward

    f(c) = ‖P(c) − t‖²  +  μ Σ_i (s_i (c_i − r_i))²      subject to  lo ≤ c ≤ hi

(the objective of :func:`core.rig.solve.solve_controls`: ``P`` the rig's evaluation, ``r`` the rest controls,
``s`` the natural scales) within a *fixed budget* of rig evaluations, so a frame costs at most ``budget`` depsgraph
updates whatever the capture does:

- the frame starts from the previous frame's controls, their verified evaluation and the previous Jacobian
  (a stream is smooth: the previous frame is a good start and its Jacobian still holds);
- each trial step is the bounded Levenberg–Marquardt step on the carried Jacobian (the drag's step,
  :func:`core.rig.solve.bounded_step`: a primal active set, SciPy's bounded least squares as fallback), verified
  by one rig evaluation and accepted only when the objective does not increase; every evaluation corrects the
  Jacobian by Broyden's rank-one update (:func:`core.rig.solve.broyden_update`);
- when a frame has converged short of every pin (the Gauss–Newton step moves no pin by more than ``xtol``, or
  no step predicts a decrease), the next frame starts by refreshing the Jacobian's columns at these controls by
  forward differences, in turn: one, or all the budget but one evaluation when the Jacobian shows it is stale (a
  trial was refused, or no step predicts a decrease; with a budget of one: one column, only then), so the
  carried Jacobian never goes stale on a long stream, and the frame's last evaluation is usually its accepted
  trial (the rig already shows what is written).

A frame is ``OK`` when every pin is within ``pin_tol``, when the Gauss–Newton step on the carried Jacobian would
move no pin by more than ``xtol``, or when no bounded step predicts a decrease; it is ``NOT_CONVERGED`` when the
budget ran out first (``budget_hit``; its value is still the best controls verified this frame, never worse
than the previous frame's).  Nothing here keeps a frame waiting: the caller counts the budget hits and shows them.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from numpy.typing import ArrayLike

from ..blas_threads import single_threaded
from ..errors import ErrorCode
from ..result import Result, ShapeSpaceError, Status
from .solve import bounded_step, broyden_update

__all__ = ["LiveRigFrame", "LiveRigSolver", "ridge_unit"]


@dataclass(kw_only=True)
class LiveRigFrame(Result):
    """Outcome of one :meth:`LiveRigSolver.step` (``value``: the controls (n,)).

    Attributes
    ----------
    points : ndarray (p, 3)
        The rig's verified evaluation at ``value``.
    pin_errors : ndarray (p,)
        ``‖P_k(value) − t_k‖``.
    objective : float
    evaluations : int
        Rig evaluations this frame (trial steps and column refreshes), at most the budget.
    trials : int
        Trial steps evaluated.
    refreshed : int
        Jacobian columns refreshed by finite differences this frame (at its start, at the previous controls).
    budget_hit : bool
        The budget ran out before the frame converged (``status`` NOT_CONVERGED).
    last_evaluated : ndarray (n,) or None
        The controls of the frame's last rig evaluation (None when none): when they differ from ``value`` the
        rig shows a refused trial or a finite-difference probe, not ``value``.
    last_points : ndarray (p, 3) or None
        The rig's evaluation at ``last_evaluated`` (what the rig shows): the caller writes ``value`` back (one
        more evaluation) only when these are visibly worse than ``points`` for the frame's targets.
    """

    points: np.ndarray = None
    pin_errors: np.ndarray = None
    objective: float = np.nan
    evaluations: int = 0
    trials: int = 0
    refreshed: int = 0
    budget_hit: bool = False
    last_evaluated: np.ndarray = None
    last_points: np.ndarray = None


def ridge_unit(J: np.ndarray, scale: ArrayLike) -> float:
    """The ridge's unit of :func:`core.rig.take.solve_take`: ``tr(JᵀJ)/n / mean(s²)`` for a Jacobian ``J``
    (3p, n) and natural scales ``s`` (n,), so ``μ = reg · unit`` weighs the ridge like a take's."""
    s = np.asarray(scale, dtype=np.float64)
    return float(np.einsum("ij,ij->", J, J)) / J.shape[1] / float(np.mean(s * s))


class LiveRigSolver:
    """The state a live stream carries from frame to frame onto one rig (module doc).

    Parameters
    ----------
    c0 : array_like (n,)
        Controls at the start (inside ``lo``/``hi``).
    points : array_like (p, 3)
        The rig's evaluation at ``c0``.
    jacobian : array_like (3p, n)
        The Jacobian of ``points`` at ``c0`` (computed once when the stream starts).
    lo, hi : array_like (n,)
        Bounds (``lo == hi`` holds a channel).
    scale : array_like (n,)
        Natural scales ``s`` (positive).
    steps : array_like (n,)
        Finite-difference steps of the column refreshes (positive).
    rest : array_like (n,)
        Controls ``r`` the ridge pulls toward.
    mu : float
        Ridge weight ``μ`` ≥ 0 (use ``reg · ridge_unit(jacobian, scale)``).
    pin_tol, xtol : float
        Stopping distances of a frame (module doc; 0: off).
    budget : int
        Rig evaluations per frame, ≥ 1.
    """

    def __init__(self, c0, points, jacobian, *, lo, hi, scale, steps, rest, mu: float, pin_tol: float,
                 xtol: float, budget: int):
        self.c = np.array(c0, dtype=np.float64).reshape(-1)
        n = self.c.size
        self.P = np.array(points, dtype=np.float64)
        if self.P.ndim != 2 or self.P.shape[1] != 3 or not np.all(np.isfinite(self.P)):
            raise ShapeSpaceError(f"points: expected finite (p, 3), got {self.P.shape}", ErrorCode.SHAPE)
        self.J = np.array(jacobian, dtype=np.float64)
        if self.J.shape != (self.P.size, n) or not np.all(np.isfinite(self.J)):
            raise ShapeSpaceError(f"jacobian: expected finite ({self.P.size}, {n}), got {self.J.shape}",
                                  ErrorCode.SHAPE)
        vec = [np.array(v, dtype=np.float64).reshape(-1) for v in (lo, hi, scale, steps, rest)]
        if any(v.shape != (n,) for v in vec):
            raise ShapeSpaceError(f"lo, hi, scale, steps and rest: expected {n} values each", ErrorCode.SHAPE)
        self.lo, self.hi, self.s, self.h, self.ref = vec
        if not (np.all(self.s > 0) and np.all(np.isfinite(self.s)) and np.all(self.h > 0)):
            raise ShapeSpaceError("scale and steps must be positive", ErrorCode.RANGE)
        if int(budget) < 1:
            raise ShapeSpaceError(f"budget = {budget}: at least one evaluation per frame", ErrorCode.RANGE)
        if not (np.isfinite(mu) and mu >= 0):
            raise ShapeSpaceError(f"mu = {mu} must be a non-negative number", ErrorCode.RANGE)
        self.reg_w = float(mu) * self.s * self.s
        self.pin_tol, self.xtol, self.budget = float(pin_tol), float(xtol), int(budget)
        self.lam = 1e-3
        self.cursor = 0                       # the next Jacobian column to refresh
        self.pending = 0                      # columns to refresh at the start of the next frame

    def objective(self, P: np.ndarray, c: np.ndarray, t: np.ndarray) -> tuple:
        """``(residual (3p,), f)`` of points ``P`` (p, 3) at controls ``c`` (n,) for targets ``t`` (p, 3)."""
        e = (P - t).reshape(-1)
        return e, float(e @ e + np.sum(self.reg_w * (c - self.ref) ** 2))

    def _checked(self, evaluate, x) -> np.ndarray:
        out = np.asarray(evaluate(x), dtype=np.float64)
        if out.shape != self.P.shape or not np.all(np.isfinite(out)):
            raise ShapeSpaceError(f"the rig evaluated {out.shape} points (finite {self.P.shape} expected) for "
                                  f"controls {np.round(x, 6).tolist()}", ErrorCode.NON_FINITE)
        return out

    def _converged(self, t, e, f) -> tuple:
        """(reason to stop with OK or '', the trial step)."""
        if self.pin_tol > 0 and np.max(np.linalg.norm(self.P - t, axis=1)) <= self.pin_tol:
            return "every pin within tolerance", None
        J, c = self.J, self.c
        D2 = np.maximum(np.einsum("ij,ij->j", J, J) + self.reg_w, 1e-12 * np.max(self.s * self.s))
        d_gn = bounded_step(J, e, self.reg_w, c, self.ref, 1e-9, D2, self.lo, self.hi)
        if self.xtol > 0 and np.max(np.linalg.norm((J @ d_gn).reshape(-1, 3), axis=1)) <= self.xtol:
            return "the Gauss–Newton step moves no pin by more than xtol", None
        d = d_gn if self.lam <= 1e-9 else bounded_step(J, e, self.reg_w, c, self.ref, self.lam, D2, self.lo,
                                                         self.hi)
        r = e + J @ d
        pred = f - float(r @ r + np.sum(self.reg_w * (c + d - self.ref) ** 2))
        if not np.any(d) or pred <= 1e-12 * f:
            return "no bounded step predicts a decrease", None
        return "", (d, pred)

    def _refresh(self, evaluate, count: int) -> tuple:
        """Refresh ``count`` Jacobian columns (in turn) by forward differences at the current controls; returns
        (the controls evaluated last or None, their points or None, the evaluations made: a held channel's
        column needs none)."""
        last, last_P, made = None, None, 0
        n = self.c.size
        for _ in range(min(count, n)):
            i = self.cursor
            self.cursor = (self.cursor + 1) % n
            up, down = self.hi[i] - self.c[i], self.c[i] - self.lo[i]
            if up <= 0.0 and down <= 0.0:
                continue
            step = min(self.h[i], up) if up >= self.h[i] or up >= down else -min(self.h[i], down)
            x = self.c.copy()
            x[i] += step
            Pi = self._checked(evaluate, x)
            last, last_P, made = x, Pi, made + 1
            self.J[:, i] = (Pi - self.P).reshape(-1) / (x[i] - self.c[i])
        return last, last_P, made

    def step(self, evaluate: Callable, targets: ArrayLike) -> LiveRigFrame:
        """One frame (module doc): move the controls toward ``targets`` (p, 3) within the budget.

        Parameters
        ----------
        evaluate : callable (n,) -> (p, 3)
            The rig's points for a control vector (leaves the rig showing those controls).
        targets : array_like (p, 3)

        Returns
        -------
        LiveRigFrame
            The solver's state moves on to ``value``.  A target or an evaluation that is refused (non-finite,
            wrong shape) raises :class:`~core.result.ShapeSpaceError` and leaves the state as it was.
        """
        t = np.asarray(targets, dtype=np.float64)
        if t.shape != self.P.shape:
            raise ShapeSpaceError(f"targets: expected {self.P.shape}, got {t.shape}", ErrorCode.SHAPE)
        if not np.all(np.isfinite(t)):
            raise ShapeSpaceError(f"targets: point {int(np.flatnonzero(~np.isfinite(t).all(1))[0])} is not finite",
                                  ErrorCode.NON_FINITE)
        saved = (self.c, self.P, self.J.copy(), self.lam, self.cursor, self.pending)
        try:
            with single_threaded():          # small dense blocks: BLAS threads would only spin (core.blas_threads)
                return self._frame(evaluate, t)
        except BaseException:
            self.c, self.P, self.J, self.lam, self.cursor, self.pending = saved
            raise

    def _frame(self, evaluate, t) -> LiveRigFrame:
        e, f = self.objective(self.P, self.c, t)
        used, trials, last, last_P, reason, refused = 0, 0, None, None, "", False
        refreshed = min(self.pending, self.budget - 1) if self.budget > 1 else self.pending
        if refreshed:                        # the columns the last frame asked for, at its controls (still these)
            last, last_P, used = self._refresh(evaluate, refreshed)
        self.pending = 0
        while True:
            reason, trial = self._converged(t, e, f)
            if reason or used >= self.budget:
                break
            d, pred = trial
            c_new = np.clip(self.c + d, self.lo, self.hi)
            P_new = self._checked(evaluate, c_new)
            used, trials, last, last_P = used + 1, trials + 1, c_new, P_new
            e_new, f_new = self.objective(P_new, c_new, t)
            self.J = broyden_update(self.J, c_new - self.c, (P_new - self.P).reshape(-1))
            rho = (f - f_new) / pred
            if f_new <= f:
                self.c, self.P, e, f = c_new, P_new, e_new, f_new
                self.lam = self.lam / 3.0 if rho > 0.75 else (self.lam * 2.0 if rho < 0.25 else self.lam)
            else:
                self.lam = min(self.lam * 4.0, 1e12)
                refused = True
        if reason and reason != "every pin within tolerance":
            stale = refused or reason == "no bounded step predicts a decrease"
            self.pending = min(self.c.size, self.budget - 1 if stale else 1) if self.budget > 1 else int(stale)
        self.lam = max(self.lam, 1e-12)
        errs = np.linalg.norm(self.P - t, axis=1)
        hit = not reason
        message = reason or (f"the budget of {self.budget} rig evaluations ran out, pins up to "
                             f"{errs.max():.3g} away")
        return LiveRigFrame(self.c.copy(), status=Status.NOT_CONVERGED if hit else Status.OK, message=message,
                            iterations=trials, points=self.P.copy(), pin_errors=errs, objective=f,
                            evaluations=used, trials=trials, refreshed=refreshed, budget_hit=hit,
                            last_evaluated=None if last is None else np.array(last),
                            last_points=None if last_P is None else np.array(last_P))
