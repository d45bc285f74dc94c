"""Pin-and-drag direct manipulation of blendshape sliders (thesis ch. 4).

The artist pins surface points and drags them; the sliders follow.  For a
linear rig the solve is thesis Eq. 4.5,

    min_w ‖R w − m‖² + α‖w − w0‖² + μ‖w‖²   subject to  lo ≤ w ≤ hi,

where ``R`` (3k × n) holds the delta-matrix rows of the k pinned surface
points (barycentric combinations of a triangle's vertices), ``m`` their
targets minus the neutral, ``w0`` the sliders before the drag and
``[lo, hi]`` each key's slider range.  Positions are first rescaled so the
model's bounding-box diagonal measures :data:`NORMALISED_DIAGONAL` (30, a
real head's diagonal in centimetres, the scale the thesis' α = 0.1 and
μ = 0.001 were tuned at), so α and μ mean the same for a rig in metres,
centimetres or facecap's int16 units.

Learned mode (thesis 4.3) replaces ``α‖w − w0‖²`` by a prior learned from
earlier animation (:class:`WeightPrior`), either literally in PCA
coefficients (Eq. 4.8) or — the default — as a regularised covariance in
weight space that still reaches expressions outside the training span.
Mode snapping (Eq. 4.9) optionally pulls the first three PCA coefficients
toward the mean of nearby training frames.

Rigs with in-between or combination shapes are nonlinear in ``w``: the solve
is Gauss–Newton on the same bounded problem, each step an exact bounded QP
on the linearisation followed by a backtracking search on the true
objective, so the objective decreases monotonically; it stops when the
relative decrease falls below ``gn_tol`` or after ``gn_max_iter`` steps.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..blendshape import BlendshapeModel
from ..boxqp import solve_box_lsq_dual, solve_box_qp
from ..result import ShapeSpaceError

#: Positions are measured as if the model's bounding-box diagonal were this long (a head in cm).
NORMALISED_DIAGONAL = 30.0

__all__ = ["NORMALISED_DIAGONAL", 
    "Pin", "WeightPrior", "DragResult", "pin_matrix", "pin_rest_positions", "pin_positions",
    "train_prior", "solve_drag", "solve_drag_reference", "drag_objective",
]


@dataclass(frozen=True)
class Pin:
    """A point on the surface: ``Σ weights[i] · vertex[vertices[i]]``.

    Parameters
    ----------
    vertices : tuple of int
        1–3 vertex indices (a vertex, an edge point or a triangle point).
    weights : tuple of float
        Barycentric weights, same length, summing to 1.
    """

    vertices: tuple
    weights: tuple = (1.0,)

    @staticmethod
    def at_vertex(index: int) -> "Pin":
        return Pin((int(index),), (1.0,))


def _pin_arrays(pins, p):
    if len(pins) == 0:
        raise ShapeSpaceError("no pins: add at least one pin", "no_pins")
    k = len(pins)
    idx = np.zeros((k, 3), dtype=np.int64)
    bary = np.zeros((k, 3))
    for j, pin in enumerate(pins):
        v = tuple(int(i) for i in pin.vertices)
        b = tuple(float(x) for x in pin.weights)
        if not 1 <= len(v) <= 3 or len(v) != len(b):
            raise ShapeSpaceError(f"pin {j}: vertices and weights must have 1–3 matching entries", "pin")
        if any(i < 0 or i >= p for i in v):
            raise ShapeSpaceError(f"pin {j}: vertex index out of range 0..{p - 1}", "pin")
        if not np.isfinite(b).all() or abs(sum(b) - 1.0) > 1e-6:
            raise ShapeSpaceError(f"pin {j}: barycentric weights must be finite and sum to 1", "pin")
        idx[j, :len(v)] = v
        bary[j, :len(b)] = b
    return idx, bary


class _PinRows:
    """Everything a solve needs about the pins, computed once: rows of B, rest positions, driven rows."""

    def __init__(self, model: BlendshapeModel, pins):
        self.model = model
        self.idx, self.bary = _pin_arrays(pins, model.n_vertices)
        self.R = _rows(model, self.idx, self.bary)
        self.rest = np.einsum("kc,kcx->kx", self.bary, model.neutral[self.idx])
        self.Rd = None if model.is_linear else _rows(model, self.idx, self.bary, model.driven_deltas())
        self.unit = _unit(model)

    def positions(self, w) -> np.ndarray:
        pos = self.rest + (self.R @ self.model.effective_weights(w)).reshape(-1, 3)
        if self.Rd is not None:
            pos = pos + (self.Rd @ self.model.driven_values(w)).reshape(-1, 3)
        return pos

    def objective(self, targets, w, w0, alpha, mu, prior):
        data = float(np.sum(((self.positions(w) - targets) / self.unit) ** 2))
        dw = np.asarray(w, dtype=np.float64) - w0
        if prior is None:
            reg = alpha * float(dw @ dw)
        else:
            a, cols, sgn, _ = _prior_terms(prior, alpha, w0)
            reg = a * float(dw @ dw) + float(sum((s * (c.T @ dw)) @ (c.T @ dw) for c, s in zip(cols, sgn)))
        return data + reg + mu * float(np.asarray(w) @ np.asarray(w))

    def linearised(self, targets, x, sides=None, linear_only=False):
        """Normalised rows and right-hand side of the (linearised) data term at ``x``: ‖R w − m‖²."""
        R = self.R / self.unit
        m = (targets - self.rest).reshape(-1) / self.unit
        if self.Rd is not None and not linear_only:
            driven = self.Rd / self.unit
            slopes = self.model.driven_slopes(x, sides)
            m = m - driven @ (self.model.driven_values(x) - slopes @ x)
            R = R + driven @ slopes
        return R, m


def pin_matrix(model: BlendshapeModel, pins, deltas=None) -> np.ndarray:
    """Rows of the delta matrix at the pins, ``R`` of shape (3k, n) (thesis Eq. 4.5).

    Muted keys get zero columns (Blender ignores them).  ``deltas`` (t, p, 3)
    overrides the model's targets (used for the driven keys' Jacobian).
    """
    idx, bary = _pin_arrays(pins, model.n_vertices)
    return _rows(model, idx, bary, deltas)


def _rows(model, idx, bary, deltas=None):
    d = model.deltas if deltas is None else deltas
    gathered = d[:, idx, :]                                   # (t, k, 3 vertices, 3 coords)
    rows = (gathered * bary[None, :, :, None]).sum(axis=2)    # (t, k, 3)
    rows = np.ascontiguousarray(rows.reshape(d.shape[0], -1).T)  # (3k, t)
    if deltas is None:
        rows[:, model.mute] = 0.0
    return rows


def pin_rest_positions(model: BlendshapeModel, pins) -> np.ndarray:
    """Neutral positions of the pins, (k, 3)."""
    idx, bary = _pin_arrays(pins, model.n_vertices)
    return np.einsum("kc,kcx->kx", bary, model.neutral[idx])


def pin_positions(model: BlendshapeModel, pins, weights) -> np.ndarray:
    """Pin positions on the face at slider values ``weights``, (k, 3) — as Blender evaluates."""
    idx, bary = _pin_arrays(pins, model.n_vertices)
    w = model.effective_weights(weights)
    pos = pin_rest_positions(model, pins) + (pin_matrix(model, pins) @ w).reshape(-1, 3)
    if not model.is_linear:
        driven = pin_matrix(model, pins, model.driven_deltas())
        pos = pos + (driven @ model.driven_values(weights)).reshape(-1, 3)
    return pos


@dataclass
class WeightPrior:
    """A Gaussian prior on slider values learned from animation (thesis 4.3).

    Attributes
    ----------
    names : list of str
        Slider names, in the model's order.
    mean : ndarray, shape (n,)
    components : ndarray, shape (n, r)
        Orthonormal principal directions (columns), largest variance first.
    variances : ndarray, shape (r,)
        PCA variances λ_k (> 0).
    coefficients : ndarray, shape (f, r)
        Training frames' PCA coefficients (for mode snapping, Eq. 4.9).
    eps : float
        Covariance regulariser as a fraction of the mean variance.
    """

    names: list
    mean: np.ndarray
    components: np.ndarray
    variances: np.ndarray
    coefficients: np.ndarray
    eps: float = 0.1

    @property
    def unit(self) -> float:
        """Mean variance: the prior's natural unit."""
        return float(self.variances.mean())

    def to_coefficients(self, w) -> np.ndarray:
        """Affine map w → c = Uᵀ(w − mean)."""
        return (np.asarray(w, dtype=np.float64) - self.mean) @ self.components

    def to_weights(self, c) -> np.ndarray:
        """Affine map c → w = mean + U c."""
        return self.mean + np.asarray(c, dtype=np.float64) @ self.components.T

    def aligned(self, names) -> "WeightPrior":
        """This prior re-indexed to a rig's slider order (keys it never saw get no variance)."""
        names = list(names)
        missing = [n for n in self.names if n not in names]
        if missing:
            raise ShapeSpaceError(
                f"the prior was trained on shape keys that no longer exist: {', '.join(missing[:5])}; "
                "train it again", "prior_stale")
        if names == list(self.names):
            return self
        pos = [names.index(n) for n in self.names]
        mean = np.zeros(len(names))
        comp = np.zeros((len(names), self.components.shape[1]))
        mean[pos] = self.mean
        comp[pos] = self.components
        return WeightPrior(names, mean, comp, self.variances, self.coefficients, self.eps)


def train_prior(weights, names, eps: float = 0.1, energy: float = 1.0) -> WeightPrior:
    """Learn a :class:`WeightPrior` from animation frames.

    Parameters
    ----------
    weights : array_like, shape (f, n)
        Slider values of the training frames (e.g. sampled actions).
    names : sequence of str, length n
    eps : float
        Regulariser (fraction of the mean variance) added to the covariance.
    energy : float
        Keep the leading components that explain this fraction of variance
        (default: every direction the data moves in; the regulariser ``eps``
        keeps the rest reachable).

    Raises
    ------
    ShapeSpaceError
        Fewer than 2 frames, or no slider varies.
    """
    w = np.asarray(weights, dtype=np.float64)
    names = list(names)
    if w.ndim != 2 or w.shape[1] != len(names):
        raise ShapeSpaceError(f"weights must have shape (frames, {len(names)}), got {w.shape}", "shape")
    if w.shape[0] < 2:
        raise ShapeSpaceError(f"a prior needs at least 2 frames of animation, got {w.shape[0]}", "prior_frames")
    if not np.isfinite(w).all():
        raise ShapeSpaceError("the training animation contains NaN or infinite values", "non_finite")
    mean = w.mean(axis=0)
    centred = w - mean
    _, sv, vt = np.linalg.svd(centred, full_matrices=False)
    var = sv ** 2 / max(w.shape[0] - 1, 1)
    if var.size == 0 or var[0] <= 1e-12:
        raise ShapeSpaceError("the training animation moves none of the shape keys", "prior_constant")
    cum = np.cumsum(var) / var.sum()
    r = var.size if energy >= 1.0 else int(np.searchsorted(cum, energy) + 1)
    r = max(1, min(r, int(np.sum(var > 1e-12 * var[0]))))
    comp = vt[:r].T
    return WeightPrior(names, mean, comp, var[:r], centred @ comp, eps)


@dataclass
class DragResult:
    """Outcome of a drag solve.

    Attributes
    ----------
    weights : ndarray, shape (n,)
    objective : float
        Value of the (normalised) objective at ``weights``.
    residuals : ndarray, shape (k,)
        Distance of each pin from its target, in the model's units.
    iterations : int
        QP iterations (summed over Gauss–Newton steps).
    status : int
        0 ok, 1 ok with warnings, negative on failure.
    message : str
    diagnostics : dict
    """

    weights: np.ndarray
    objective: float
    residuals: np.ndarray
    iterations: int
    status: int
    message: str
    diagnostics: dict = field(default_factory=dict)


def _unit(model) -> float:
    """Model units per normalised unit (see :data:`NORMALISED_DIAGONAL`)."""
    return (model.scale or NORMALISED_DIAGONAL) / NORMALISED_DIAGONAL


def _bounds(model, w0):
    lo = model.slider_min.copy()
    hi = model.slider_max.copy()
    mute = model.mute
    lo[mute] = hi[mute] = np.clip(w0[mute], model.slider_min[mute], model.slider_max[mute])
    return lo, hi


def _prior_terms(prior: WeightPrior, alpha, w0, pca_snap=None):
    """Identity weight, low-rank columns, signs and linear term of the learned prior.

    Prior metric ``P = σ̄² (Σ_r + ε σ̄² I)⁻¹ = (1/ε) I − U diag(γ) Uᵀ`` with
    ``γ_k = 1/ε − σ̄²/(λ_k + ε σ̄²) ≥ 0``: moves along the training data's
    principal directions are cheap, moves outside its span cost ``1/ε`` times
    the plain mode's, so every expression stays reachable.
    """
    unit = prior.unit
    e = prior.eps * unit
    gamma = 1.0 / prior.eps - unit / (prior.variances + e)
    keep = gamma > 1e-12
    U = prior.components[:, keep]
    a = alpha / prior.eps
    cols = [U]
    sgn = [-alpha * gamma[keep]]
    lin = a * w0 - U @ (alpha * gamma[keep] * (U.T @ w0))
    if pca_snap is not None:
        U3, target, beta = pca_snap
        cols.append(U3)
        sgn.append(np.full(U3.shape[1], beta))
        lin = lin + U3 @ (beta * target)
    return a, cols, sgn, lin


def drag_objective(model, pins, targets, w, w0, alpha=0.1, mu=0.001, prior: WeightPrior = None):
    """The normalised objective of Eq. 4.5 (or its learned variant) at ``w``."""
    prior = prior.aligned(model.names) if prior is not None else None
    return _PinRows(model, pins).objective(np.asarray(targets, dtype=np.float64), w,
                                           np.asarray(w0, dtype=np.float64), alpha, mu, prior)


def _validate(model, pins, targets, w0):
    targets = np.asarray(targets, dtype=np.float64)
    k = len(pins)
    if targets.shape != (k, 3):
        raise ShapeSpaceError(f"targets must have shape ({k}, 3) for {k} pins, got {targets.shape}", "shape")
    if not np.isfinite(targets).all():
        raise ShapeSpaceError("pin targets contain NaN or infinite coordinates", "non_finite")
    w0 = model.values if w0 is None else np.asarray(w0, dtype=np.float64)
    if w0.shape != (model.n_targets,):
        raise ShapeSpaceError(f"w0 must have shape ({model.n_targets},), got {w0.shape}", "shape")
    if not np.isfinite(w0).all():
        raise ShapeSpaceError("w0 contains NaN or infinite slider values", "non_finite")
    return targets, np.clip(w0, model.slider_min, model.slider_max)


def _snap_term(prior: WeightPrior, w, dims=3):
    """Eq. 4.9: mean of training coefficients within σ_i/3 of ``w`` in the first ``dims`` PCA dims."""
    d = min(dims, prior.components.shape[1])
    c = prior.to_coefficients(w)[:d]
    sigma = np.sqrt(prior.variances[:d])
    near = np.all(np.abs(prior.coefficients[:, :d] - c) <= sigma / 3.0, axis=1)
    if not near.any():
        return None, 0
    target_c = prior.coefficients[near, :d].mean(axis=0)
    U3 = prior.components[:, :d] / np.sqrt(prior.variances[:d] / prior.unit)   # whitened to the prior unit
    return (U3, target_c / np.sqrt(prior.variances[:d] / prior.unit) + U3.T @ prior.mean), int(near.sum())


def solve_drag(model: BlendshapeModel, pins, targets, w0=None, alpha: float = 0.1, mu: float = 0.001,
               prior: WeightPrior = None, prior_form: str = "covariance", snap: bool = False,
               x0=None, warm: "DragResult" = None, gn_tol: float = 1e-10, gn_max_iter: int = 30) -> DragResult:
    """Solve for slider values that take the pins to their targets (thesis Eq. 4.5, 4.8, 4.9).

    Parameters
    ----------
    model : BlendshapeModel
    pins : sequence of Pin, length k
        Moving and stationary pins alike (a stationary pin's target is its
        current position).
    targets : array_like, shape (k, 3)
        Target positions in the model's object space.
    w0 : array_like, shape (n,), optional
        Sliders before the drag (default ``model.values``).
    alpha, mu : float
        Thesis defaults 0.1 and 0.001, in size-normalised units.
    prior : WeightPrior, optional
        Learned mode.  ``prior_form="covariance"`` (default) or ``"pca"``
        (Eq. 4.8 literally: PCA coefficients bounded by ``3√λ``).
    snap : bool
        Mode snapping (Eq. 4.9) after the solve; needs ``prior``.
    x0 : array_like, shape (n,), optional
        Primal warm start.
    warm : DragResult, optional
        The previous mouse-move's result: its weights and dual variables
        warm-start this solve (the active set changes little during a drag).

    Returns
    -------
    DragResult
    """
    targets, w0 = _validate(model, pins, targets, w0)
    if alpha < 0 or mu < 0 or alpha + mu <= 0:
        raise ShapeSpaceError(f"alpha and mu must be non-negative with a positive sum, got {alpha}, {mu}", "range")
    if snap and prior is None:
        raise ShapeSpaceError("mode snapping needs a learned prior", "no_prior")
    if prior is not None:
        prior = prior.aligned(model.names)
    if prior_form not in ("covariance", "pca"):
        raise ShapeSpaceError(f"prior_form must be 'covariance' or 'pca', got {prior_form!r}", "range")
    key = tuple((tuple(p.vertices), tuple(p.weights)) for p in pins)
    cached = warm.diagnostics.get("_rows") if warm is not None else None
    rows = cached if cached is not None and cached.key == key and cached.model is model else _PinRows(model, pins)
    rows.key = key
    lo, hi = _bounds(model, w0)
    x = np.clip(w0 if x0 is None else np.asarray(x0, dtype=np.float64), lo, hi)
    total_it = 0
    solver_status = 0
    diag = {"unit": rows.unit}
    warm_dual = None
    if warm is not None and len(warm.weights) == model.n_targets:
        x = np.clip(warm.weights, lo, hi) if x0 is None else x
        warm_dual = warm.diagnostics.get("dual")
    if prior is not None and prior_form == "pca":
        x, total_it, solver_status = _solve_pca(rows, targets, w0, alpha, mu, prior, lo, hi)
        diag["prior_form"] = "pca"
    else:
        snap_term = None
        passes = 2 if snap else 1
        for pass_ in range(passes):
            x, it, st = _gauss_newton(rows, targets, w0, alpha, mu, prior, lo, hi, x, snap_term, gn_tol,
                                      gn_max_iter, warm_dual, diag)
            total_it += it
            solver_status = max(solver_status, st)
            if snap and pass_ == 0:
                snap_term, count = _snap_term(prior, x)
                diag["snap_neighbours"] = count
                if snap_term is None:
                    break
                U3, tgt = snap_term
                snap_term = (U3, tgt, alpha)
    residuals = np.linalg.norm(rows.positions(x) - targets, axis=1)
    messages = _warnings(rows, pins, targets, residuals)
    if solver_status:
        messages.append("the solver stopped before full convergence (weights are the best found)")
    obj = rows.objective(targets, x, w0, alpha, mu, prior if prior_form == "covariance" else None)
    diag.update({"clamped": int(np.sum((x <= lo + 1e-12) | (x >= hi - 1e-12))), "_rows": rows})
    return DragResult(x, obj, residuals, total_it, 1 if messages else 0,
                      "; ".join(messages) if messages else "ok", diag)


def _solve_linearised(R, m, w0, alpha, mu, prior, lo, hi, x, snap_term, dual=None, out=None):
    """One bounded QP: data ‖R w − m‖² plus the regularisers; returns (w, iterations, status).

    ``dual`` warm-starts the plain mode's dual solve; ``out`` (dict) receives the final dual.
    """
    if prior is None and snap_term is None:
        # Eq. 4.5: Hessian (α+μ)I + RᵀR — solved through its 3k-dimensional dual; when the
        # regularisation is so weak that the dual converges slowly, finish in the primal.
        c = alpha + mu
        dual0 = dual if dual is not None and np.shape(dual) == (R.shape[0],) else None
        res = solve_box_lsq_dual(R, m, c, alpha * w0 / c, lo, hi, dual0=dual0, max_iter=40)
        if out is not None:
            out["dual"] = res.dual
        if res.status == 0:
            return res.x, res.iterations, 0
        p = solve_box_qp(2.0 * c, R.T, np.full(R.shape[0], 2.0), 2.0 * (R.T @ m + alpha * w0), lo, hi, x0=res.x)
        return p.x, res.iterations + p.iterations, p.status
    if prior is None:
        U3, tgt, beta = snap_term
        a, cols, sgn, lin = alpha, [U3], [np.full(U3.shape[1], beta)], alpha * w0 + U3 @ (beta * tgt)
    else:
        a, cols, sgn, lin = _prior_terms(prior, alpha, w0, snap_term)
    V = np.hstack([R.T] + cols)
    s = np.concatenate([np.ones(R.shape[0])] + sgn)
    keep = s != 0
    res = solve_box_qp(2.0 * (a + mu), V[:, keep], 2.0 * s[keep], 2.0 * (R.T @ m + lin), lo, hi, x0=x)
    return res.x, res.iterations, res.status


def _gauss_newton(rows, targets, w0, alpha, mu, prior, lo, hi, x, snap_term, tol, max_iter, dual=None, out=None):
    """Damped Gauss–Newton; a single exact QP for linear rigs.  Returns (w, iterations, status).

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
    if rows.Rd is None:
        R, m = rows.linearised(targets, x)
        return _solve_linearised(R, m, w0, alpha, mu, prior, lo, hi, x, snap_term, dual, out)

    def true_obj(w):
        val = rows.objective(targets, w, w0, alpha, mu, prior)
        if snap_term is not None:
            U3, tgt, beta = snap_term
            r = U3.T @ w - tgt
            val += beta * float(r @ r)
        return val

    model = rows.model
    kinked = sorted({ib.primary for ib in model.inbetweens})

    def choose_sides(x, f):
        """+1/−1 per slider: at a tent's kink, the side whose piece the objective decreases into."""
        sides = np.ones(model.n_targets)
        for i in kinked:
            knots = model.knots_of(i)
            if np.min(np.abs(knots - x[i])) > 1e-7:
                continue
            h = 1e-6
            up = true_obj(np.where(np.arange(x.size) == i, min(x[i] + h, hi[i]), x)) - f
            down = true_obj(np.where(np.arange(x.size) == i, max(x[i] - h, lo[i]), x)) - f
            sides[i] = -1.0 if down < up else 1.0
        return sides

    def piece_bounds(x, sides):
        """Keep each kinked slider inside the piece it enters: the tents are then exactly linear."""
        lo2, hi2 = lo.copy(), hi.copy()
        for i in kinked:
            a, b = model.segment(i, x[i], int(sides[i]))
            lo2[i], hi2[i] = max(lo[i], a), min(hi[i], b)
        return lo2, hi2

    def descend(x):
        total, status = 0, 0
        f = true_obj(x)
        for _ in range(max_iter):
            sides = choose_sides(x, f)
            lo2, hi2 = piece_bounds(x, sides)
            R, m = rows.linearised(targets, x, sides)
            cand, it, st = _solve_linearised(R, m, w0, alpha, mu, prior, lo2, hi2, x, snap_term)
            total += it
            status = max(status, st)
            step = cand - x
            t, f_new = 1.0, true_obj(cand)
            while f_new > f and t > 1e-6:
                t *= 0.5
                f_new = true_obj(x + t * step)
            if not f_new < f:
                break
            done = f - f_new <= tol * max(f, 1e-300)
            x, f = x + t * step, f_new
            if done:
                break
        return x, f, total, status

    R, m = rows.linearised(targets, x, linear_only=True)
    x_lin, it0, _ = _solve_linearised(R, m, w0, alpha, mu, prior, lo, hi, x, snap_term)
    a = descend(x)
    b = descend(x_lin)
    best = a if a[1] <= b[1] else b
    return best[0], a[2] + b[2] + it0, best[3]


def _solve_pca(rows, targets, w0, alpha, mu, prior, lo, hi):
    """Thesis Eq. 4.8: PCA coefficients c = √Λ z with |z_k| ≤ 3 (i.e. |c_k| ≤ 3√λ_k)."""
    if rows.Rd is not None:
        raise ShapeSpaceError("the PCA prior form needs a rig without in-betweens or combinations", "nonlinear")
    R, m = rows.linearised(targets, w0)
    L = prior.components * np.sqrt(prior.variances / prior.unit)          # n × r, whitened to the unit
    Rz = R @ L
    mz = m - R @ prior.mean
    z0 = prior.to_coefficients(w0) / np.sqrt(prior.variances / prior.unit)
    bound = 3.0 * np.sqrt(prior.unit)
    res = solve_box_qp(2.0 * (alpha + mu), Rz.T, np.full(Rz.shape[0], 2.0), 2.0 * (Rz.T @ mz + alpha * z0),
                       np.full(L.shape[1], -bound), np.full(L.shape[1], bound), x0=np.clip(z0, -bound, bound))
    w = np.clip(prior.mean + L @ res.x, lo, hi)   # Blender clamps sliders to their range anyway
    return w, res.iterations, res.status


def _warnings(rows, pins, targets, residuals):
    out = []
    model = rows.model
    size = model.scale
    moving = np.abs(rows.R).reshape(len(pins), -1).max(axis=1) > 1e-9 * size
    dead = [j for j in range(len(pins)) if not moving[j]]
    if dead:
        out.append(f"pins {', '.join(map(str, dead))} are on points no shape key moves")
    keyed = {}
    for j in range(len(pins)):
        key = tuple(np.round(np.concatenate([rows.idx[j], rows.bary[j]]), 9))
        if key in keyed and np.linalg.norm(targets[j] - targets[keyed[key]]) > 1e-9 * size:
            out.append(f"pins {keyed[key]} and {j} share a point but have different targets: both are met halfway")
        keyed.setdefault(key, j)
    far = np.flatnonzero(residuals > 0.05 * size).tolist()
    if far:
        out.append(f"pins {', '.join(map(str, far))} cannot reach their targets within the slider ranges")
    return out


def solve_drag_reference(model: BlendshapeModel, pins, targets, w0=None, alpha=0.1, mu=0.001) -> np.ndarray:
    """The same linear problem (Eq. 4.5) by an independent solver, scipy's bounded least squares.

    Used by tests and benchmarks; not for interaction.
    """
    from scipy.optimize import lsq_linear

    targets, w0 = _validate(model, pins, targets, w0)
    if not model.is_linear:
        raise ShapeSpaceError("the reference solver handles linear rigs only", "nonlinear")
    scale = _unit(model)
    R = pin_matrix(model, pins) / scale
    m = (targets - pin_rest_positions(model, pins)).reshape(-1) / scale
    n = model.n_targets
    A = np.vstack([R, np.sqrt(alpha) * np.eye(n), np.sqrt(mu) * np.eye(n)])
    b = np.concatenate([m, np.sqrt(alpha) * w0, np.zeros(n)])
    lo, hi = _bounds(model, w0)
    fixed = lo == hi
    if fixed.any():  # lsq_linear needs lo < hi: eliminate fixed (muted) sliders
        b = b - A[:, fixed] @ lo[fixed]
        A = A[:, ~fixed]
    res = lsq_linear(A, b, bounds=(lo[~fixed], hi[~fixed]), method="bvls", tol=1e-15)
    w = lo.copy()
    w[~fixed] = res.x
    return w
