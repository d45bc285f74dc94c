"""Pins onto any differentiable rig: bounded, regularised Levenberg–Marquardt in control space.

The direct-manipulation problem of thesis ch. 4 on a rig that is not linear in its controls: find the
control vector ``c`` (n,) that minimises ::

    f(c) = Σ_k w_k ‖P_k(c) − t_k‖²  +  μ Σ_i (s_i (c_i − r_i))²      subject to  lo ≤ c ≤ hi

where ``P(c)`` (p, 3) are the surface points of the pins for the controls (the rig's evaluation), ``t`` (p, 3)
their targets, ``r`` (n,) the reference controls the solve is pulled toward (the current or rest pose),
``s`` (n,) the channels' natural scales (surface displacement per unit, so both terms are squared lengths)
and ``μ`` a small dimensionless weight.

With a learned prior (``prior``, :class:`~core.rig.prior.ControlPrior`: thesis 4.3 on the controls, the Learned
mode of a drag) the regulariser is the full quadratic ``(c − r)ᵀ W (c − r)`` with the prior's metric
``W = λ Σ⁻¹`` (n, n) in place of ``μ Σ_i (s_i (c_i − r_i))²`` — still centred on the reference ``r`` (the controls at
mouse-down), as the linear path's Learned mode (:func:`core.manipulation.prior.prior_terms`) centres
``α (w − w0)ᵀ P (w − w0)`` on the weights at mouse-down: the prior's covariance only says which moves are cheap
(channels the animation moves together move along), it never pulls the face toward the training mean.  Every
step's Hessian gets ``W`` and its gradient ``W (c − r)``, the bounded steps and the stopping tests are the same.
Without a prior the diagonal regulariser's arithmetic is exactly the one it always was.

Method (Levenberg–Marquardt on the box; Moré 1978, with Broyden's rank-one update between Jacobians):

- The Jacobian ``J = ∂P/∂c`` (3p, n) comes from the caller (``jacobian``) or by forward finite differences,
  one evaluation per channel, steps pointing into the box.  It is kept between iterations and corrected by
  Broyden's rank-one update ``J += (ΔP − J d) dᵀ / dᵀd`` after every evaluated trial step.
- Each step solves the bounded linear least-squares problem ``min ‖J d + e‖² + μ‖S(c + d − r)‖² + λ‖D d‖²``
  (with a prior: ``+ (c + d − r)ᵀ λΣ⁻¹ (c + d − r)`` in place of the second term)
  on ``lo − c ≤ d ≤ hi − c`` exactly (a dense primal active set, :func:`box_qp_primal`, warm-started from the
  previous step's active sets, falling back on SciPy's bounded least squares), with Marquardt's scaling
  ``D² = diag(JᵀJ + μS²)`` (with a prior: ``diag(JᵀJ + λΣ⁻¹)``).
- A step is accepted only when the rig, evaluated again at the new controls, gives an objective that does
  not increase; otherwise ``λ`` grows.  When a step is refused or *stalls* (actual decrease below a quarter
  of the predicted one) on a Broyden-updated Jacobian, the Jacobian is recomputed at the current controls
  before anything else — or, with ``defer_refresh``, the solve stops there (an interactive move keeps its
  verified step and leaves the refresh to an idle moment or the release).  A deferring solve on a Broyden-updated
  Jacobian therefore never grows ``λ`` (any refused step stops it): its trial step is the bounded Gauss–Newton
  step its ``xtol`` test has just computed (one bounded solve per verified step, not two).

Stopping: ``OK`` when every pin is within ``pin_tol`` of its target, or when, on a freshly computed Jacobian,
the bounded Gauss–Newton step predicts a decrease below ``ftol`` × f (first-order stationarity on the box, up
to the evaluation's rounding), or when a step computed on a fresh Jacobian is refused although no channel moves
by more than its finite-difference step (stationary to the resolution of the Jacobian: a smaller step is
below what the Jacobian can resolve), or — with ``xtol`` > 0 — when the bounded Gauss–Newton step on the current
Jacobian, fresh or Broyden-updated, would move no pin by more than ``xtol`` (a take's frames, :mod:`.take`);
``NOT_CONVERGED`` (value: the best controls found, which never have a higher
objective than the start) at the iteration limit, when no step decreases the objective although the model
predicts one, or where a deferred refresh stops it.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from numpy.typing import ArrayLike
from scipy.linalg import cho_factor, cho_solve
from scipy.optimize import lsq_linear

from ..errors import ErrorCode
from ..result import Result, ShapeSpaceError, Status
from .prior import ControlPrior

__all__ = ["RigSolveResult", "bounded_step", "box_qp_primal", "broyden_update", "finite_difference_jacobian",
           "solve_controls"]


@dataclass(kw_only=True)
class RigSolveResult(Result):
    """Outcome of :func:`solve_controls` (``value``: the controls (n,), also readable as ``x``).

    Attributes
    ----------
    points : ndarray (p, 3)
        The rig's evaluation at ``value`` (the last verified evaluation, not a prediction).
    pin_errors : ndarray (p,)
        Distances ``‖P_k(value) − t_k‖``.
    objective : float
        ``f(value)``.
    objective_start : float
        ``f`` at the start.
    evaluations : int
        Rig evaluations made (trial steps and finite differences).
    jacobians : int
        Jacobians computed (finite differences or the caller's), the first included.
    jacobian : ndarray (3p, n)
        The last Jacobian (fresh or Broyden-updated, unweighted rows; zero rows for zero-weight pins): a start
        for the next solve near ``value`` (``first_jacobian``; a take's next frame).
    """

    points: np.ndarray = None
    pin_errors: np.ndarray = None
    objective: float = np.nan
    objective_start: float = np.nan
    evaluations: int = 0
    jacobians: int = 0
    jacobian: np.ndarray = None

    @property
    def x(self) -> np.ndarray:
        return self.value

    @property
    def pin_error_max(self) -> float:
        return float(np.max(self.pin_errors)) if self.pin_errors is not None and self.pin_errors.size else 0.0


def finite_difference_jacobian(evaluate: Callable, c: ArrayLike, steps: ArrayLike, lo: ArrayLike, hi: ArrayLike,
                               base: ArrayLike | None = None) -> np.ndarray:
    """Forward-difference Jacobian of ``evaluate`` at ``c``, one evaluation per channel, steps into the box.

    Parameters
    ----------
    evaluate : callable (n,) -> (p, 3)
    c : array_like (n,)
    steps : array_like (n,)
        Positive step per channel; a channel whose box is narrower than its step on both sides uses the wider
        side; a channel with ``lo == hi`` gets a zero column (it cannot move).
    lo, hi : array_like (n,)
    base : array_like (p, 3), optional
        ``evaluate(c)`` when already known.

    Returns
    -------
    ndarray (3p, n) float64
    """
    c = np.asarray(c, dtype=np.float64)
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    h = np.abs(np.asarray(steps, dtype=np.float64))
    p0 = np.asarray(evaluate(c) if base is None else base, dtype=np.float64).reshape(-1)
    J = np.zeros((p0.size, c.size))
    for i in range(c.size):
        up, down = hi[i] - c[i], c[i] - lo[i]
        if up <= 0.0 and down <= 0.0:
            continue
        hi_ = min(h[i], up) if up >= h[i] or up >= down else -min(h[i], down)
        ci = c.copy()
        ci[i] += hi_
        J[:, i] = (np.asarray(evaluate(ci), dtype=np.float64).reshape(-1) - p0) / (ci[i] - c[i])
    return J


def broyden_update(J: np.ndarray, d: ArrayLike, dp: ArrayLike) -> np.ndarray:
    """Broyden's rank-one secant update of a Jacobian, in place and returned.

    ``J`` (m, n) becomes ``J + (dp − J d) dᵀ / dᵀd`` so that ``J d = dp`` (the observed change ``dp`` (m,) for
    the step ``d`` (n,)); a zero step leaves ``J`` unchanged.
    """
    d = np.asarray(d, dtype=np.float64)
    dd = float(d @ d)
    if dd > 0.0:
        J += np.outer(np.asarray(dp, dtype=np.float64) - J @ d, d / dd)
    return J


def box_qp_primal(H: np.ndarray, g: np.ndarray, lo: np.ndarray, hi: np.ndarray, max_iter: int | None = None,
                  lower: np.ndarray | None = None, upper: np.ndarray | None = None) -> np.ndarray | None:
    """Minimiser of ``½ xᵀHx − gᵀx`` on ``lo ≤ x ≤ hi`` (dense SPD ``H`` (n, n), ``lo ≤ 0 ≤ hi`` (n,)) by the
    primal active-set method (Nocedal & Wright, *Numerical Optimization*, alg. 16.3, for bounds).

    From ``x = 0`` with the entries on a bound that the gradient pushes out held (and those of ``lower`` /
    ``upper`` (n,) bool, a previous solve's active sets, at their bounds): solve the free block exactly
    (Cholesky); step toward that point until the first bound blocks it (hold that entry) or, when it is feasible,
    release the held entry whose multiplier points most into the box — finite for SPD ``H``, one small solve per
    change of the active set.  (:func:`core.boxqp.active_set_dense`, the primal–dual method, cycles on the
    ill-conditioned steps (cond ~1e10) of a face with many sliders on their bounds.)

    Returns
    -------
    ndarray (n,) or None
        The KKT point, or None at the iteration limit (``10 n + 20`` by default) or when a free block is not
        positive definite.
    """
    n = g.size
    fixed = hi <= lo
    lower = fixed | ((lo >= 0) & (g < 0)) | (False if lower is None else lower & np.isfinite(lo))
    upper = ~lower & (((hi <= 0) & (g > 0)) | (False if upper is None else upper & np.isfinite(hi)))
    x = np.where(lower, np.minimum(lo, hi), np.where(upper, hi, 0.0))
    tol = 1e-12 * (np.abs(g).max() + 1e-300)
    for _ in range(10 * n + 20 if max_iter is None else max_iter):
        held = lower | upper
        f = np.flatnonzero(~held)
        target = x.copy()
        if f.size:                                            # only the free entries: no division by zero
            try:
                factor = cho_factor(H[f[:, None], f], check_finite=False)
            except np.linalg.LinAlgError:
                return None
            h = np.flatnonzero(held)
            target[f] = cho_solve(factor, g[f] - H[f[:, None], h] @ x[h] if h.size else g[f], check_finite=False)
            p = target[f] - x[f]
            down, up = p < 0, p > 0
            room = np.full(f.size, np.inf)
            room[down] = (lo[f[down]] - x[f[down]]) / p[down]
            room[up] = (hi[f[up]] - x[f[up]]) / p[up]
            j = int(np.argmin(room))
            if room[j] < 1.0:                                 # a bound blocks the way: go there and hold it
                k = f[j]
                x = x + max(room[j], 0.0) * (target - x)
                x[k] = lo[k] if p[j] < 0 else hi[k]
                lower[k], upper[k] = p[j] < 0, p[j] > 0
                continue
        x = target
        mult = g - H @ x                                      # −∇: > 0 pushes up, < 0 pushes down
        push = np.where(lower & ~fixed, mult, 0.0) - np.where(upper, mult, 0.0)
        k = int(np.argmax(push))
        if push[k] <= tol:
            return np.clip(x, lo, hi)
        lower[k] = upper[k] = False
    return None


#: The damping of the step the stopping tests take for the (bounded, regularised) Gauss–Newton step.
_GN_LAMBDA = 1e-9


def bounded_step(J: np.ndarray, e: np.ndarray, reg_w: np.ndarray, c: np.ndarray, ref: np.ndarray, lam: float,
                 D2: np.ndarray, lo: np.ndarray, hi: np.ndarray, held: tuple | None = None) -> np.ndarray:
    """The bounded LM step: argmin ‖J d + e‖² + Σ reg_w (c + d − ref)² + λ Σ D2 d² on lo − c ≤ d ≤ hi − c
    (``held``: (at lo, at hi) (n,) bool of a previous step's end point, a warm start).

    ``reg_w`` (n,) is a diagonal regulariser; (n, n) a full symmetric positive semi-definite one ``W``, the
    term then ``(c + d − ref)ᵀ W (c + d − ref)`` (a learned prior: ``W = λΣ⁻¹``, ``ref`` the reference)."""
    if reg_w.ndim == 2:
        return _bounded_step_full(J, e, reg_w, c, ref, lam, D2, lo, hi, held)
    H = J.T @ J + np.diag(reg_w + lam * D2)
    g = -(J.T @ e) - reg_w * (c - ref)
    dlo, dhi = np.minimum(lo - c, 0.0), np.maximum(hi - c, 0.0)
    d = box_qp_primal(H, g, dlo, dhi, lower=None if held is None else held[0],
                      upper=None if held is None else held[1])
    if d is None:
        a = np.sqrt(reg_w + lam * D2)
        A = np.vstack([J, np.diag(a)])
        b = np.concatenate([-e, -reg_w * (c - ref) / np.where(a > 0, a, 1.0)])
        free = dhi > dlo
        d = np.zeros_like(c)
        if free.any():
            d[free] = lsq_linear(A[:, free], b, bounds=(dlo[free], dhi[free]), method="bvls").x
    return np.clip(d, dlo, dhi)


def _bounded_step_full(J, e, W, c, ref, lam, D2, lo, hi, held):
    """:func:`bounded_step` with a full regulariser ``W`` (n, n)."""
    A2 = W + np.diag(lam * D2)
    H = J.T @ J + A2
    g = -(J.T @ e) - W @ (c - ref)
    dlo, dhi = np.minimum(lo - c, 0.0), np.maximum(hi - c, 0.0)
    d = box_qp_primal(H, g, dlo, dhi, lower=None if held is None else held[0],
                      upper=None if held is None else held[1])
    if d is None:                       # ‖J d + e‖² + ‖Lᵀd + L⁻¹W(c − ref)‖², L Lᵀ = W + λ D2
        L = np.linalg.cholesky(A2 + 1e-300 * np.eye(c.size))
        A = np.vstack([J, L.T])
        b = np.concatenate([-e, -np.linalg.solve(L, W @ (c - ref))])
        free = dhi > dlo
        d = np.zeros_like(c)
        if free.any():
            d[free] = lsq_linear(A[:, free], b, bounds=(dlo[free], dhi[free]), method="bvls").x
    return np.clip(d, dlo, dhi)


def _reg_value(reg_w, x, ref) -> float:
    """The regulariser at ``x``: ``Σ reg_w (x − ref)²`` (diagonal) or ``(x − ref)ᵀ W (x − ref)`` (full)."""
    if reg_w.ndim == 2:
        dx = x - ref
        return float(dx @ reg_w @ dx)
    return float(np.sum(reg_w * (x - ref) ** 2))


def _model(J, e, reg_w, c, ref, d):
    """The Gauss–Newton model of f at c + d."""
    r = e + J @ d
    return float(r @ r + _reg_value(reg_w, c + d, ref))


def _check_inputs(c0, targets, lo, hi, scale, weights, reference):
    c0 = np.array(c0, dtype=np.float64).reshape(-1)
    n = c0.size
    if n == 0:
        raise ShapeSpaceError("no controls to solve for", ErrorCode.NO_CHANNELS)
    t = np.array(targets, dtype=np.float64)
    if t.ndim != 2 or t.shape[1] != 3 or t.shape[0] == 0:
        raise ShapeSpaceError(f"targets: expected (p, 3) with p ≥ 1, got {t.shape}", ErrorCode.NO_PINS)

    def vec(v, name, default, finite=True):
        out = np.full(n, default, np.float64) if v is None else np.array(v, dtype=np.float64).reshape(-1)
        if out.shape != (n,):
            raise ShapeSpaceError(f"{name}: expected {n} values, got {out.size}", ErrorCode.SHAPE)
        bad = np.flatnonzero(np.isnan(out) | (~np.isfinite(out) if finite else False))
        if bad.size:
            raise ShapeSpaceError(f"{name}: entry {bad[0]} is {out[bad[0]]}", ErrorCode.NON_FINITE)
        return out

    c0 = vec(c0, "controls", 0.0)
    lo, hi = vec(lo, "lo", -np.inf, False), vec(hi, "hi", np.inf, False)
    bad = np.flatnonzero((c0 < lo) | (c0 > hi))
    if bad.size:
        i = bad[0]
        raise ShapeSpaceError(f"controls: channel {i} = {c0[i]} lies outside [{lo[i]}, {hi[i]}]", ErrorCode.RANGE)
    s = vec(scale, "scale", 1.0)
    if np.any(s <= 0):
        raise ShapeSpaceError(f"scale: channel {int(np.flatnonzero(s <= 0)[0])} is not positive", ErrorCode.RANGE)
    if not np.all(np.isfinite(t)):
        raise ShapeSpaceError(f"targets: pin {int(np.flatnonzero(~np.isfinite(t).all(1))[0])} is not finite",
                              ErrorCode.NON_FINITE)
    w = np.ones(t.shape[0]) if weights is None else np.array(weights, dtype=np.float64).reshape(-1)
    if w.shape != (t.shape[0],) or not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ShapeSpaceError(f"weights: expected {t.shape[0]} non-negative numbers", ErrorCode.INVALID)
    ref = c0.copy() if reference is None else vec(reference, "reference", 0.0)
    return c0, t, lo, hi, s, w, ref


def solve_controls(evaluate: Callable, c0: ArrayLike, targets: ArrayLike, *, lo: ArrayLike | None = None,
                   hi: ArrayLike | None = None, scale: ArrayLike | None = None, jacobian: Callable | None = None,
                   steps: ArrayLike | None = None, weights: ArrayLike | None = None,
                   reference: ArrayLike | None = None, mu: float = 1e-6, pin_tol: float = 0.0,
                   ftol: float = 1e-10, max_iter: int = 50, first_jacobian: np.ndarray | None = None,
                   first_points: np.ndarray | None = None, xtol: float = 0.0,
                   defer_refresh: bool = False, first_active: tuple | None = None,
                   prior: ControlPrior | None = None) -> RigSolveResult:
    """Controls that bring the pins to their targets (bounded, regularised Levenberg–Marquardt; module doc).

    Parameters
    ----------
    evaluate : callable (n,) -> (p, 3)
        The rig's surface points of the pins for a control vector (any float dtype; read as float64).
    c0 : array_like (n,)
        Start (inside the bounds).
    targets : array_like (p, 3)
    lo, hi : array_like (n,), optional
        Box bounds (infinite by default; ``lo == hi`` holds a channel).
    scale : array_like (n,), optional
        Natural scales ``s`` (ones by default).
    jacobian : callable (n,), (p, 3) -> (3p, n), optional
        The Jacobian at ``c`` given ``evaluate(c)``; forward finite differences by default.
    steps : array_like (n,), optional
        Finite-difference steps (``1e-3 / s`` by default: a thousandth of a surface unit); also the resolution
        below which a refused step on a fresh Jacobian counts as stationary (pass the steps a supplied
        ``jacobian`` uses).
    weights : array_like (p,), optional
        Non-negative pin weights ``w`` (ones by default).
    reference : array_like (n,), optional
        Controls ``r`` the regulariser pulls toward (``c0`` by default).
    mu : float
        Regularisation weight ``μ`` ≥ 0 (dimensionless).
    pin_tol : float
        Stop as soon as every pin is within this distance of its target (0: only stationarity stops).
    ftol : float
        Relative predicted decrease below which a fresh-Jacobian step counts as stationary.
    max_iter : int
        Trial steps (each one rig evaluation) before ``NOT_CONVERGED``.
    first_jacobian : ndarray (3p, n), optional
        A Jacobian already known at ``c0`` (a cached one; counted as Broyden-updated, so it is refreshed before
        it can stop the solve).
    first_points : ndarray (p, 3), optional
        ``evaluate(c0)`` when already known.
    xtol : float
        Also stop (``OK``) when the bounded Gauss–Newton step on the current Jacobian, fresh or Broyden-updated,
        would move no pin by more than this distance (0: off).  A take solved frame after frame stops on it
        without recomputing the Jacobian every frame.
    defer_refresh : bool
        Never recompute a Broyden-updated Jacobian (``first_jacobian``) inside this solve: where the solve would
        (a step on it is refused, stalls or predicts no decrease), it stops instead — ``NOT_CONVERGED`` with
        ``diagnostics["jacobian_stale"]`` True, the value the last verified controls — and leaves the refresh to
        the caller (a drag's next idle moment or its release, :mod:`bridge.rig.drag`).  A mouse move then costs
        its verified step(s) and never ``n`` evaluations; with ``xtol`` > 0 each of those steps is the bounded
        Gauss–Newton step the ``xtol`` test computed (module doc).  Without ``first_jacobian`` the first Jacobian
        is still computed.
    first_active : (ndarray (n,) bool, ndarray (n,) bool), optional
        Channels a previous solve's last step left on their lower / upper bounds (its ``diagnostics["active"]``):
        a warm start for the bounded steps (only their speed depends on it).
    prior : ControlPrior, optional
        A learned prior on the controls (:func:`core.rig.prior.train_control_prior`): the regulariser becomes
        ``(c − r)ᵀ λΣ⁻¹ (c − r)`` around the same ``reference`` ``r`` (module doc) and ``mu`` is not used.

    Returns
    -------
    RigSolveResult
    """
    c, t, lo, hi, s, w, ref = _check_inputs(c0, targets, lo, hi, scale, weights, reference)
    if not (np.isfinite(mu) and mu >= 0):
        raise ShapeSpaceError(f"mu = {mu} must be a non-negative number", ErrorCode.RANGE)
    if max_iter < 1:
        raise ShapeSpaceError(f"max_iter = {max_iter} must be at least 1", ErrorCode.RANGE)
    h = 1e-3 / s if steps is None else np.array(steps, dtype=np.float64).reshape(-1)
    if h.shape != c.shape or not np.all(np.isfinite(h) & (h > 0)):
        raise ShapeSpaceError(f"steps: expected {c.size} positive numbers", ErrorCode.RANGE)
    run = _LevenbergMarquardt(evaluate, jacobian, t, lo, hi, s, w, ref, mu, h)
    if prior is not None:
        run.reg_w = _check_prior(prior, c.size)
    run.defer = bool(defer_refresh)
    if first_active is not None:
        run.held = tuple(np.asarray(a, bool).reshape(c.shape) for a in first_active)
    run.start(c, first_points, first_jacobian)
    status, message = Status.NOT_CONVERGED, ""
    while True:
        stop = run.converged(pin_tol, ftol, xtol)
        if stop is not None:
            status, message = Status.OK, stop
            break
        if run.it >= max_iter:
            message = (f"stopped after {run.it} steps, pins up to "
                       f"{np.max(np.linalg.norm(run.P - t, axis=1)):.3g} away")
            break
        run.it += 1
        stop = run.trial()
        if stop is not None:
            status, message = stop
            break
        run.lam = max(run.lam, 1e-12)
    return run.result(status, message)


def _check_prior(prior: ControlPrior, n: int) -> np.ndarray:
    """The metric ``λΣ⁻¹`` (n, n) of a prior for ``n`` controls (refused when it does not match or is not finite)."""
    W = np.asarray(prior.precision, dtype=np.float64)
    if W.shape != (n, n):
        raise ShapeSpaceError(f"prior: trained on {W.shape[0] if W.ndim else 0} channels, the solve has {n}",
                              ErrorCode.SHAPE)
    if not np.isfinite(W).all():
        raise ShapeSpaceError("prior: its precision is not finite", ErrorCode.NON_FINITE)
    return 0.5 * (W + W.T)


class _LevenbergMarquardt:
    """The state and steps of one :func:`solve_controls` run (inputs already checked)."""

    def __init__(self, evaluate, jacobian, t, lo, hi, s, w, ref, mu, h):
        self.evaluate, self.jacobian = evaluate, jacobian
        self.t, self.lo, self.hi, self.s, self.ref, self.h = t, lo, hi, s, ref, h
        self.sw = np.repeat(np.sqrt(w), 3)
        self.reg_w = mu * s * s
        self.evaluations = self.jacobians = 0
        self.lam, self.it = 1e-3, 0
        self.defer, self.stale = False, False
        self.held = None
        self.d_next = None

    # ---------------------------------------------------------------- the rig
    def points(self, x):
        self.evaluations += 1
        out = np.asarray(self.evaluate(x), dtype=np.float64)
        if out.shape != self.t.shape:
            raise ShapeSpaceError(f"the rig evaluated {out.shape} points, expected {self.t.shape}", ErrorCode.SHAPE)
        if not np.all(np.isfinite(out)):
            raise ShapeSpaceError("the rig evaluated non-finite points for controls "
                                  f"{np.round(x, 6).tolist()}", ErrorCode.NON_FINITE)
        return out

    def jac(self, x, px):
        self.jacobians += 1
        if self.jacobian is not None:
            out = np.asarray(self.jacobian(x, px), dtype=np.float64)
        else:
            out = finite_difference_jacobian(self.points, x, self.h, self.lo, self.hi, base=px)
        if out.shape != (self.t.size, x.size) or not np.all(np.isfinite(out)):
            raise ShapeSpaceError(f"Jacobian: expected finite ({self.t.size}, {x.size}), got {out.shape}",
                                  ErrorCode.SHAPE)
        return out * self.sw[:, None]

    def objective(self, px, x):
        e = (px - self.t).reshape(-1) * self.sw
        return e, float(e @ e + _reg_value(self.reg_w, x, self.ref))

    def refresh(self):
        self.J, self.fresh = self.jac(self.c, self.P), True

    def stale_stop(self, why):
        """Refresh the Broyden-updated Jacobian — or, deferring, the ``(status, message)`` that stops the run."""
        if not self.defer:
            self.refresh()
            return None
        self.stale = True
        return Status.NOT_CONVERGED, f"Jacobian refresh deferred: {why} on the Broyden-updated Jacobian"

    # ---------------------------------------------------------------- the iteration
    def start(self, c, first_points, first_jacobian):
        self.c = c
        self.P = self.points(c) if first_points is None else \
            np.array(first_points, dtype=np.float64).reshape(self.t.shape)
        self.e, self.f = self.objective(self.P, c)
        self.f_start = self.f
        self.history = [self.f]
        if first_jacobian is not None:
            self.J = np.array(first_jacobian, dtype=np.float64).reshape(self.t.size, c.size) * self.sw[:, None]
            self.fresh = False
        else:
            self.refresh()

    def step(self, lam):
        """The bounded LM step for ``lam`` from the current controls, warm-started from the last step's active
        sets (which it updates)."""
        d = bounded_step(self.J, self.e, self.reg_w, self.c, self.ref, lam, self.D2, self.lo, self.hi, self.held)
        x = self.c + d
        self.held = (x <= self.lo) & (self.hi > self.lo), x >= self.hi
        return d

    def converged(self, pin_tol, ftol, xtol):
        """The reason to stop with ``OK`` before the next trial step, or None."""
        if pin_tol > 0 and np.max(np.linalg.norm(self.P - self.t, axis=1)) <= pin_tol:
            return "every pin within tolerance"
        J, e, c = self.J, self.e, self.c
        reg_diag = self.reg_w if self.reg_w.ndim == 1 else np.diag(self.reg_w)
        self.D2 = np.maximum(np.einsum("ij,ij->j", J, J) + reg_diag, 1e-12 * np.max(self.s * self.s))
        self.d_next = None
        if not (self.fresh or xtol > 0):
            return None
        d_gn = self.step(_GN_LAMBDA)
        if self.defer and not self.fresh:
            self.d_next = d_gn              # a deferring run's trial step on a Broyden-updated Jacobian (trial())
        if self.fresh and self.f - _model(J, e, self.reg_w, c, self.ref, d_gn) <= ftol * self.f + 1e-300:
            return "stationary on the bounds"
        if xtol > 0:
            moved = (J @ d_gn / np.where(self.sw > 0, self.sw, 1.0)).reshape(-1, 3)
            if np.max(np.linalg.norm(moved, axis=1)) <= xtol:
                return "the Gauss–Newton step moves no pin by more than xtol"
        return None

    def trial(self):
        """One trial step (verified by evaluating the rig); ``(status, message)`` when the run must stop."""
        stalled = (Status.NOT_CONVERGED, "stalled: no step decreases the objective although the model predicts one")
        d = self.step(self.lam) if self.d_next is None else self.d_next
        self.d_next = None
        was_fresh = self.fresh
        pred = self.f - _model(self.J, self.e, self.reg_w, self.c, self.ref, d)
        if not np.any(d) or pred <= 0.0:
            if not self.fresh:
                return self.stale_stop("the step predicts no decrease")
            if self.lam > 1e12:
                return stalled
            self.lam *= 10.0
            return None
        c_new = np.clip(self.c + d, self.lo, self.hi)
        P_new = self.points(c_new)
        e_new, f_new = self.objective(P_new, c_new)
        self.J = broyden_update(self.J, c_new - self.c, e_new - self.e)
        rho = (self.f - f_new) / pred
        if f_new <= self.f:
            self.c, self.P, self.e, self.f = c_new, P_new, e_new, f_new
            self.history.append(f_new)
            self.fresh = False
            self.lam = self.lam / 3.0 if rho > 0.75 else (self.lam * 2.0 if rho < 0.25 else self.lam)
            if rho < 0.25 and not was_fresh:
                return self.stale_stop(f"a step gained {rho:.2g} of its prediction")
        elif not self.fresh:
            return self.stale_stop("a step was refused")
        elif np.all(np.abs(c_new - self.c) <= self.h):
            return Status.OK, "stationary to the resolution of the Jacobian"
        else:
            self.lam *= 4.0
            if self.lam > 1e12:
                return stalled
        return None

    def result(self, status, message) -> RigSolveResult:
        errs = np.linalg.norm(self.P - self.t, axis=1)
        J = self.J / np.where(self.sw > 0, self.sw, 1.0)[:, None]
        return RigSolveResult(self.c, status=status, message=message, iterations=self.it, points=self.P,
                              pin_errors=errs, objective=self.f, objective_start=self.f_start,
                              evaluations=self.evaluations, jacobians=self.jacobians, jacobian=J,
                              diagnostics={"lambda": self.lam, "pin_error_max": float(errs.max()),
                                           "objective_history": self.history, "jacobian_stale": self.stale,
                                           "active": self.held})
