"""The drag solve: slider values that take the pins to their targets (thesis Eq. 4.5, 4.8, 4.9).

For a linear rig the solve is thesis Eq. 4.5,

    min_w ‖R w − m‖² + α‖w − w0‖² + μ‖w‖²   subject to  lo ≤ w ≤ hi,

where ``R`` (3k × n) holds the delta-matrix rows of the k pinned surface
points (:class:`~.pins.PinRows`), ``m`` their targets minus the neutral,
``w0`` the sliders before the drag and ``[lo, hi]`` each key's slider range.
Positions are first rescaled so the model's bounding-box diagonal measures
:data:`~core.blendshape.NORMALISED_DIAGONAL` (30, a real head's diagonal in
centimetres, the scale the thesis' α = 0.1 and μ = 0.001 were tuned at), so
α and μ mean the same for a rig in metres, centimetres or facecap's int16
units.  The plain mode is solved through the QP's small dual
(:func:`~core.boxqp.solve_box_lsq_dual`), other modes as a bounded QP with an
identity-plus-low-rank Hessian (:func:`~core.boxqp.solve_box_qp`).

Learned mode (thesis 4.3) replaces ``α‖w − w0‖²`` by a prior learned from
earlier animation (:mod:`.prior`), either literally in PCA coefficients
(Eq. 4.8) or — the default — as a regularised covariance in weight space.
Mode snapping (Eq. 4.9) optionally pulls the first three PCA coefficients
toward the mean of nearby training frames.

Rigs with in-between or combination shapes are nonlinear in ``w``: the solve
is Gauss–Newton on the same bounded problem, each step an exact bounded QP
on the linearisation followed by a backtracking search on the true
objective, so the objective decreases monotonically; it stops when the
relative decrease falls below ``gn_tol`` or after ``gn_max_iter`` steps.

An interactive drag passes a :class:`~.session.DragSession` to every solve:
it carries the pin rows, the previous sliders and the previous dual from one
mouse move to the next.

Every route leaves two kinds of sliders exactly at ``w0`` (bounds ``lo = hi``):
muted keys, and keys that move no vertex (:func:`~.rig.inert_keys` — nothing
in the data term decides them, and an invisible change would still be keyed).
A model with a NaN or infinite coordinate or slider range is refused by name
(:func:`~.rig.check_model`), as are non-finite targets, ``w0``, ``x0`` and
regularisers; a solver stopped at its iteration limit makes the result
``NOT_CONVERGED``, its message starting "not converged".
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..blendshape import BlendshapeModel, normalised_unit
from ..boxqp import solve_box_lsq_dual, solve_box_qp
from ..errors import ErrorCode
from ..result import Issue, Result, ShapeSpaceError, Status
from ..validate import array, choice, non_negative, positive
from .pins import Pin, PinRows, pin_matrix, pin_rest_positions
from .prior import WeightPrior, prior_terms, snap_term
from .rig import check_model, inert_keys
from .session import DragSession

__all__ = ["DragResult", "solve_drag", "solve_drag_reference", "drag_objective"]

PRIOR_FORMS = ("covariance", "pca")


@dataclass(kw_only=True)
class DragResult(Result):
    """Outcome of a drag solve (``value``: the slider values, also readable as ``weights``).

    Attributes
    ----------
    value : ndarray, shape (n,)
        Slider values.
    objective : float
        Value of the (normalised) objective at the sliders.
    residuals : ndarray, shape (k,)
        Distance of each pin from its target, in the model's units.
    iterations : int
        QP iterations (summed over Gauss–Newton steps).
    status : Status
        ``OK``; ``WARNING`` when ``issues``/``message`` report dead pins, conflicting pins or unreachable
        targets; ``NOT_CONVERGED`` when a QP or the Gauss–Newton loop stopped at its iteration limit (the
        message says so first; the sliders are then the best found).
    diagnostics : dict
        ``unit`` (model units per normalised unit), ``clamped`` (sliders at a bound), ``inert`` (names of the
        keys that move no vertex: their sliders were left where they were), and ``prior_form`` /
        ``snap_neighbours`` when those routes ran.
    """

    objective: float
    residuals: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def weights(self) -> np.ndarray:
        """The slider values (alias of ``value``), shape (n,)."""
        return self.value


@dataclass
class _Problem:
    """One drag problem after validation: pins, targets, regularisers and slider bounds."""

    rows: PinRows
    targets: np.ndarray
    w0: np.ndarray
    alpha: float
    mu: float
    prior: WeightPrior | None
    lo: np.ndarray
    hi: np.ndarray

    def objective(self, w, prior=None, snap=None) -> float:
        """The normalised objective at ``w`` with ``prior`` (covariance form) and a snap term ``(U3, tgt, β)``."""
        val = _objective(self.rows, self.targets, w, self.w0, self.alpha, self.mu, prior)
        if snap is not None:
            U3, tgt, beta = snap
            r = U3.T @ w - tgt
            val += beta * float(r @ r)
        return val


def _objective(rows, targets, w, w0, alpha, mu, prior) -> float:
    """Eq. 4.5 (or its covariance-prior variant), normalised: data + regulariser + μ‖w‖²."""
    data = float(np.sum(((rows.positions(w) - targets) / rows.unit) ** 2))
    dw = np.asarray(w, dtype=np.float64) - w0
    if prior is None:
        reg = alpha * float(dw @ dw)
    else:
        a, cols, sgn, _ = prior_terms(prior, alpha, w0)
        reg = a * float(dw @ dw) + float(sum((s * (c.T @ dw)) @ (c.T @ dw) for c, s in zip(cols, sgn)))
    return data + reg + mu * float(np.asarray(w) @ np.asarray(w))


def _bounds(model, w0, inert):
    """Slider bounds ``(lo, hi)``; muted sliders and those of keys that move nothing (``inert``) stay at ``w0``."""
    lo = model.slider_min.copy()
    hi = model.slider_max.copy()
    fixed = model.mute | inert
    lo[fixed] = hi[fixed] = np.clip(w0[fixed], model.slider_min[fixed], model.slider_max[fixed])
    return lo, hi


def _slider_vector(values, name, model):
    """``values`` (n,) checked finite, the message naming the first bad key; clipped to the slider ranges."""
    w = array(values, name, shape=(model.n_targets,), finite=False)
    bad = np.flatnonzero(~np.isfinite(w))
    if bad.size:
        raise ShapeSpaceError(f"{name} of shape key {model.names[bad[0]]!r} is {w[bad[0]]}", ErrorCode.NON_FINITE)
    return np.clip(w, model.slider_min, model.slider_max)


def _validate(model, pins, targets, w0):
    """Checked targets (k, 3) and sliders before the drag (n,), clipped to the slider ranges."""
    k = len(pins)
    targets = array(targets, "targets", shape=(k, 3), finite=False)
    bad = np.flatnonzero(~np.isfinite(targets).all(axis=1))
    if bad.size:
        raise ShapeSpaceError(f"the target of pin {bad[0]} is not finite: {tuple(targets[bad[0]].tolist())}",
                              ErrorCode.NON_FINITE)
    w0 = _slider_vector(model.values, "value", model) if w0 is None else _slider_vector(w0, "w0", model)
    return targets, w0


def _check_prior(prior):
    """Refuse a prior with non-finite or non-positive statistics (a hand-built or damaged one)."""
    array(prior.mean, "the prior's mean", ndim=1)
    array(prior.components, "the prior's components", ndim=2)
    array(prior.coefficients, "the prior's coefficients", ndim=2)
    variances = array(prior.variances, "the prior's variances", ndim=1)
    if variances.size == 0 or np.any(variances <= 0):
        raise ShapeSpaceError("the prior's variances must be positive", ErrorCode.RANGE)
    positive(prior.eps, "the prior's eps")


def _check_settings(model, alpha, mu, prior, prior_form, snap, gn_tol, gn_max_iter):
    """Check the regularisers, the stopping rule and the learned-mode options; return the aligned prior."""
    alpha, mu = non_negative(alpha, "alpha"), non_negative(mu, "mu")
    if alpha + mu <= 0:
        raise ShapeSpaceError(f"alpha and mu must have a positive sum, got {alpha}, {mu}", ErrorCode.RANGE)
    positive(gn_tol, "gn_tol")
    if isinstance(gn_max_iter, bool) or not isinstance(gn_max_iter, (int, np.integer)) or gn_max_iter < 1:
        raise ShapeSpaceError(f"gn_max_iter must be a whole number ≥ 1, got {gn_max_iter!r}", ErrorCode.RANGE)
    if snap and prior is None:
        raise ShapeSpaceError("mode snapping needs a learned prior", ErrorCode.NO_PRIOR)
    if prior is not None:
        _check_prior(prior)
        prior = prior.aligned(model.names)
    choice(prior_form, "prior_form", PRIOR_FORMS)
    return prior


def solve_drag(model: BlendshapeModel, pins: Sequence[Pin], targets: np.ndarray, w0: np.ndarray | None = None,
               alpha: float = 0.1, mu: float = 0.001, prior: WeightPrior | None = None,
               prior_form: str = "covariance", snap: bool = False, x0: np.ndarray | None = None,
               session: DragSession | None = None, gn_tol: float = 1e-10, gn_max_iter: int = 30) -> DragResult:
    """Solve for slider values that take the pins to their targets (thesis Eq. 4.5, 4.8, 4.9).

    Parameters
    ----------
    model : BlendshapeModel
        ``n`` sliders (in-betweens and combinations make the problem nonlinear).
    pins : sequence of Pin, length k
        Moving and stationary pins alike (a stationary pin's target is its
        current position).
    targets : array_like, shape (k, 3)
        Target positions in the model's object space.
    w0 : array_like, shape (n,), optional
        Sliders before the drag (default ``model.values``).
    alpha, mu : float
        Weights of staying near ``w0`` and of small sliders (Eq. 4.5); thesis
        defaults 0.1 and 0.001, in size-normalised units.
    prior : WeightPrior, optional
        Learned mode.  ``prior_form="covariance"`` (default) or ``"pca"``
        (Eq. 4.8 literally: PCA coefficients bounded by ``3√λ``).
    snap : bool
        Mode snapping (Eq. 4.9) after the solve; needs ``prior``.
    x0 : array_like, shape (n,), optional
        Primal start (wins over the session's sliders).
    session : DragSession, optional
        The drag this solve belongs to: its pin rows, previous sliders and
        dual variables warm-start this solve (the active set changes little
        during a drag), and it records this solve's for the next one.
    gn_tol, gn_max_iter : float, int
        Gauss–Newton stopping rule for nonlinear rigs (relative decrease, steps).

    Returns
    -------
    DragResult
        Sliders (n,), objective, residuals (k,); status ``WARNING`` with a message when a pin cannot do what
        it asks, ``NOT_CONVERGED`` when a solver stopped at its iteration limit.  Sliders of keys that move
        no vertex (:func:`~.rig.inert_keys`) and muted sliders keep their ``w0``.

    Raises
    ------
    ShapeSpaceError
        Bad model, targets, ``w0``, ``x0``, regularisers, prior options or pins (codes ``shape``,
        ``non_finite`` — naming the key, vertex, pin or argument —, ``range``, ``no_prior``, ``prior_stale``,
        ``method``, ``no_pins``, ``pin``, ``nonlinear``).
    """
    rows = session.pin_rows(model, pins) if session is not None else PinRows(model, pins)
    inert = rows.inert                  # checks the model (finite) the first time these rows are used
    targets, w0 = _validate(model, pins, targets, w0)
    prior = _check_settings(model, alpha, mu, prior, prior_form, snap, gn_tol, gn_max_iter)
    x0 = None if x0 is None else _slider_vector(x0, "x0", model)
    lo, hi = _bounds(model, w0, inert)
    problem = _Problem(rows, targets, w0, float(alpha), float(mu), prior, lo, hi)
    x = np.clip(w0 if x0 is None else x0, lo, hi)
    dual = None
    start = session.start(model.n_targets) if session is not None else None
    if start is not None:
        x = np.clip(start, lo, hi) if x0 is None else x
        dual = session.dual
    diag = {"unit": rows.unit, "inert": [model.names[i] for i in np.flatnonzero(inert)]}
    if prior is not None and prior_form == "pca":
        x, iterations, solver_status = _solve_pca(problem)
        dual = None
        diag["prior_form"] = "pca"
    else:
        x, iterations, solver_status, dual = _solve_covariance(problem, x, snap, dual, gn_tol, gn_max_iter, diag)
    if session is not None:
        session.record(x, dual)
    return _result(problem, pins, x, iterations, solver_status, prior_form, diag)


def _solve_covariance(problem, x, snap, dual, gn_tol, gn_max_iter, diag):
    """Plain or covariance-prior solve, with the optional second pass of mode snapping (Eq. 4.9)."""
    total_it, solver_status, dual_out = 0, Status.OK, None
    snap_with_weight = None
    for pass_ in range(2 if snap else 1):
        x, it, st, dual_out = _gauss_newton(problem, x, snap_with_weight, gn_tol, gn_max_iter, dual)
        total_it += it
        solver_status = max(solver_status, st)
        if snap and pass_ == 0:
            term, count = snap_term(problem.prior, x)
            diag["snap_neighbours"] = count
            if term is None:
                break
            U3, tgt = term
            snap_with_weight = (U3, tgt, problem.alpha)
    return x, total_it, solver_status, dual_out


def _result(problem, pins, x, iterations, solver_status, prior_form, diag):
    """The :class:`DragResult` of sliders ``x``: residuals, warnings, objective, diagnostics."""
    rows, targets, lo, hi = problem.rows, problem.targets, problem.lo, problem.hi
    bad = np.flatnonzero(~np.isfinite(x))
    if bad.size:   # finite input can still overflow (targets near the float limit): never hand back NaN
        raise ShapeSpaceError(f"the solve gave a non-finite value for shape key {rows.model.names[bad[0]]!r} "
                              "(are the targets absurdly far?)", ErrorCode.NON_FINITE)
    residuals = np.linalg.norm(rows.positions(x) - targets, axis=1)
    issues = _warnings(rows, pins, targets, residuals)
    status = Status.WARNING if issues else Status.OK
    if solver_status == Status.NOT_CONVERGED:
        issues.insert(0, Issue("warning", "not_converged", "not converged: the solver stopped at its iteration "
                               "limit (the sliders are the best found)"))
        status = Status.NOT_CONVERGED
    obj = problem.objective(x, problem.prior if prior_form == "covariance" else None)
    diag["clamped"] = int(np.sum((x <= lo + 1e-12) | (x >= hi - 1e-12)))
    return DragResult(x, objective=obj, residuals=residuals, iterations=iterations, status=status,
                      message="; ".join(i.message for i in issues) if issues else "ok",
                      diagnostics=diag, issues=issues)


def _solve_linearised(problem, R, m, lo, hi, x, snap=None, dual=None):
    """One bounded QP: data ``‖R w − m‖²`` plus the regularisers.

    Returns ``(w, iterations, status, dual)``; ``dual`` (3k,) is the plain
    mode's final dual (``None`` on the other routes), ``dual`` in warm-starts it.
    """
    w0, alpha, mu, prior = problem.w0, problem.alpha, problem.mu, problem.prior
    if prior is None and snap is None:
        # Eq. 4.5: Hessian (α+μ)I + RᵀR — solved through its 3k-dimensional dual; when the
        # regularisation is so weak that the dual converges slowly, finish in the primal.
        c = alpha + mu
        dual0 = dual if dual is not None and np.shape(dual) == (R.shape[0],) else None
        res = solve_box_lsq_dual(R, m, c, alpha * w0 / c, lo, hi, dual0=dual0, max_iter=40)
        if res.status == Status.OK:
            return res.x, res.iterations, Status.OK, res.dual
        p = solve_box_qp(2.0 * c, R.T, np.full(R.shape[0], 2.0), 2.0 * (R.T @ m + alpha * w0), lo, hi, x0=res.x)
        return p.x, res.iterations + p.iterations, p.status, res.dual
    if prior is None:
        U3, tgt, beta = snap
        a, cols, sgn, lin = alpha, [U3], [np.full(U3.shape[1], beta)], alpha * w0 + U3 @ (beta * tgt)
    else:
        a, cols, sgn, lin = prior_terms(prior, alpha, w0, snap)
    V = np.hstack([R.T] + cols)
    s = np.concatenate([np.ones(R.shape[0])] + sgn)
    keep = s != 0
    res = solve_box_qp(2.0 * (a + mu), V[:, keep], 2.0 * s[keep], 2.0 * (R.T @ m + lin), lo, hi, x0=x)
    return res.x, res.iterations, res.status, None


def _gauss_newton(problem, x, snap, tol, max_iter, dual=None):
    """Damped Gauss–Newton; a single exact QP for linear rigs.  Returns ``(w, iterations, status, dual)``.

    In-between tents are piecewise linear, so each step keeps every slider
    that has in-betweens inside one piece (the one the objective decreases
    into, probed at a kink), where the tents are exactly linear; the bounded
    QP of that linearisation is solved exactly and the step halved until the
    true objective decreases (combinations are bilinear).  The objective is
    bounded below and strictly decreases, so the loop stops: when the
    relative decrease falls below ``tol``, when no decreasing step exists, or
    after ``max_iter`` steps.  It runs from the given start and from the
    solution that ignores the driven keys, and keeps the better end point
    (the problem is not convex).
    """
    rows = problem.rows
    if rows.Rd is None:
        R, m = rows.linearised(problem.targets, x)
        return _solve_linearised(problem, R, m, problem.lo, problem.hi, x, snap, dual)
    gn = _GaussNewton(problem, snap, tol, max_iter)
    R, m = rows.linearised(problem.targets, x, linear_only=True)
    x_lin, it0, _, _ = _solve_linearised(problem, R, m, problem.lo, problem.hi, x, snap)
    a = gn.descend(x)
    b = gn.descend(x_lin)
    best = a if a[1] <= b[1] else b
    return best[0], a[2] + b[2] + it0, best[3], None


class _GaussNewton:
    """Descent on the true objective of a nonlinear rig (see :func:`_gauss_newton`)."""

    def __init__(self, problem, snap, tol, max_iter):
        self.problem, self.snap, self.tol, self.max_iter = problem, snap, tol, max_iter
        self.model = problem.rows.model
        self.kinked = sorted({ib.primary for ib in self.model.inbetweens})

    def true_obj(self, w):
        return self.problem.objective(w, self.problem.prior, self.snap)

    def choose_sides(self, x, f):
        """+1/−1 per slider: at a tent's kink, the side whose piece the objective decreases into."""
        lo, hi = self.problem.lo, self.problem.hi
        sides = np.ones(self.model.n_targets)
        for i in self.kinked:
            knots = self.model.knots_of(i)
            if np.min(np.abs(knots - x[i])) > 1e-7:
                continue
            h = 1e-6
            up = self.true_obj(np.where(np.arange(x.size) == i, min(x[i] + h, hi[i]), x)) - f
            down = self.true_obj(np.where(np.arange(x.size) == i, max(x[i] - h, lo[i]), x)) - f
            sides[i] = -1.0 if down < up else 1.0
        return sides

    def piece_bounds(self, x, sides):
        """Keep each kinked slider inside the piece it enters: the tents are then exactly linear."""
        lo, hi = self.problem.lo, self.problem.hi
        lo2, hi2 = lo.copy(), hi.copy()
        for i in self.kinked:
            a, b = self.model.segment(i, x[i], int(sides[i]))
            lo2[i], hi2[i] = max(lo[i], a), min(hi[i], b)
        return lo2, hi2

    def descend(self, x):
        """Gauss–Newton steps from ``x``; returns ``(w, objective, iterations, status)``.

        ``status`` is ``NOT_CONVERGED`` when a step's QP did not converge or the loop used all
        ``max_iter`` steps while the objective was still decreasing by more than ``tol``.
        """
        total, status = 0, Status.OK
        f = self.true_obj(x)
        for _ in range(self.max_iter):
            sides = self.choose_sides(x, f)
            lo2, hi2 = self.piece_bounds(x, sides)
            R, m = self.problem.rows.linearised(self.problem.targets, x, sides)
            cand, it, st, _ = _solve_linearised(self.problem, R, m, lo2, hi2, x, self.snap)
            total += it
            status = max(status, st)
            step = cand - x
            t, f_new = 1.0, self.true_obj(cand)
            while f_new > f and t > 1e-6:
                t *= 0.5
                f_new = self.true_obj(x + t * step)
            if not f_new < f:
                break
            done = f - f_new <= self.tol * max(f, 1e-300)
            x, f = x + t * step, f_new
            if done:
                break
        else:
            status = Status.NOT_CONVERGED
        return x, f, total, status


def _solve_pca(problem):
    """Thesis Eq. 4.8: PCA coefficients c = √Λ z with |z_k| ≤ 3 (i.e. |c_k| ≤ 3√λ_k)."""
    rows, prior, alpha, mu, w0 = problem.rows, problem.prior, problem.alpha, problem.mu, problem.w0
    if rows.Rd is not None:
        raise ShapeSpaceError("the PCA prior form needs a rig without in-betweens or combinations",
                              ErrorCode.NONLINEAR)
    R, m = rows.linearised(problem.targets, w0)
    L = prior.components * np.sqrt(prior.variances / prior.unit)          # n × r, whitened to the unit
    Rz = R @ L
    mz = m - R @ prior.mean
    z0 = prior.to_coefficients(w0) / np.sqrt(prior.variances / prior.unit)
    bound = 3.0 * np.sqrt(prior.unit)
    res = solve_box_qp(2.0 * (alpha + mu), Rz.T, np.full(Rz.shape[0], 2.0), 2.0 * (Rz.T @ mz + alpha * z0),
                       np.full(L.shape[1], -bound), np.full(L.shape[1], bound), x0=np.clip(z0, -bound, bound))
    w = np.clip(prior.mean + L @ res.x, problem.lo, problem.hi)   # Blender clamps sliders to their range anyway
    return w, res.iterations, res.status


def _warnings(rows, pins, targets, residuals):
    """Issues of a solved drag: pins nothing moves, pins sharing a point with different targets, far pins."""
    out = []
    size = rows.model.scale
    moving = np.abs(rows.R).reshape(len(pins), -1).max(axis=1) > 1e-9 * size
    dead = [j for j in range(len(pins)) if not moving[j]]
    if dead:
        out.append(Issue("warning", "dead_pins", f"pins {', '.join(map(str, dead))} are on points no shape key moves",
                         tuple(map(str, dead))))
    keyed = {}
    points = np.round(np.concatenate([rows.idx, rows.bary], axis=1), 9).tolist()    # (k, 6): where each pin is
    for j, key in enumerate(map(tuple, points)):
        if key in keyed and np.linalg.norm(targets[j] - targets[keyed[key]]) > 1e-9 * size:
            out.append(Issue("warning", "conflicting_pins", f"pins {keyed[key]} and {j} share a point but have "
                             "different targets: both are met halfway", (str(keyed[key]), str(j))))
        keyed.setdefault(key, j)
    far = np.flatnonzero(residuals > 0.05 * size).tolist()
    if far:
        out.append(Issue("warning", "unreachable", f"pins {', '.join(map(str, far))} cannot reach their targets "
                         "within the slider ranges", tuple(map(str, far))))
    return out


def drag_objective(model: BlendshapeModel, pins: Sequence[Pin], targets: np.ndarray, w: np.ndarray,
                   w0: np.ndarray, alpha: float = 0.1, mu: float = 0.001,
                   prior: WeightPrior | None = None) -> float:
    """The normalised objective of Eq. 4.5 (or its covariance-prior variant) at ``w``.

    Parameters
    ----------
    model : BlendshapeModel
    pins : sequence of Pin, length k
    targets : array_like, shape (k, 3)
    w, w0 : array_like, shape (n,)
        Sliders to evaluate at, and before the drag.
    alpha, mu : float
    prior : WeightPrior, optional

    Returns
    -------
    float
    """
    prior = prior.aligned(model.names) if prior is not None else None
    return _objective(PinRows(model, pins), np.asarray(targets, dtype=np.float64), w,
                      np.asarray(w0, dtype=np.float64), alpha, mu, prior)


def solve_drag_reference(model: BlendshapeModel, pins: Sequence[Pin], targets: np.ndarray,
                         w0: np.ndarray | None = None, alpha: float = 0.1, mu: float = 0.001) -> np.ndarray:
    """The same linear problem (Eq. 4.5) by an independent solver, scipy's bounded least squares.

    Used by tests and benchmarks; not for interaction.

    Parameters
    ----------
    model : BlendshapeModel
        A linear rig (no in-betweens or combinations).
    pins : sequence of Pin, length k
    targets : array_like, shape (k, 3)
    w0 : array_like, shape (n,), optional
    alpha, mu : float

    Returns
    -------
    ndarray, shape (n,)
    """
    from scipy.optimize import lsq_linear

    check_model(model)
    targets, w0 = _validate(model, pins, targets, w0)
    if not model.is_linear:
        raise ShapeSpaceError("the reference solver handles linear rigs only", ErrorCode.NONLINEAR)
    scale = normalised_unit(model)
    R = pin_matrix(model, pins) / scale
    m = (targets - pin_rest_positions(model, pins)).reshape(-1) / scale
    n = model.n_targets
    A = np.vstack([R, np.sqrt(alpha) * np.eye(n), np.sqrt(mu) * np.eye(n)])
    b = np.concatenate([m, np.sqrt(alpha) * w0, np.zeros(n)])
    lo, hi = _bounds(model, w0, inert_keys(model))
    fixed = lo == hi
    if fixed.any():  # lsq_linear needs lo < hi: eliminate fixed (muted, inert) sliders
        b = b - A[:, fixed] @ lo[fixed]
        A = A[:, ~fixed]
    res = lsq_linear(A, b, bounds=(lo[~fixed], hi[~fixed]), method="bvls", tol=1e-15)
    w = lo.copy()
    w[~fixed] = res.x
    return w
