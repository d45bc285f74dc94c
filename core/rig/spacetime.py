"""Space-time retarget of a take onto any rig's controls (issue #25; thesis ch. 5 beyond a linear model).

The shape-key space-time route (:func:`core.retarget.spacetime_solver.spacetime`, as the retarget command calls it:
``relative=True``, ``anchor=True``, β = 0) minimises over the interior frames, the first and last held::

    ½ ‖D (W Bᵀ − S)‖² + ½ λ Σ_f ‖(w_f − w⁰_f) / σ‖²,     lo ≤ w ≤ hi,

``D`` the temporal first difference, ``λ = lam · tr(ΣBᵀBΣ) / n`` and ``w⁰_f`` the per-frame ridge fit
``argmin ‖w Bᵀ − s_f‖² + λ ‖w / σ‖²``.  On a rig ``g`` that is not linear in its controls the same objective,
with ``g(c_f)`` for ``w_f Bᵀ`` (targets ``T_f``), is minimised by Gauss–Newton on the whole take
(:func:`solve_take_spacetime`):

- *linearise* every frame, ``g(c_f + d_f) ≈ P_f + J_f d_f`` (the per-frame pass's points and Jacobians,
  :func:`core.rig.take.solve_take` with ``keep_linearisation``);
- *solve* the bounded quadratic in ``d`` exactly: its Hessian is block tridiagonal (blocks ``2 J_fᵀJ_f + λΣ⁻²`` and
  ``−J_fᵀJ_{f+1}``), factored in LAPACK band storage (frame-major, bandwidth ``2n − 1``), the bounds by a
  semismooth-Newton active set on the natural residual ``d − clip(d − κ∇)`` (held entries fixed at their bound,
  their rows and columns replaced by the identity), :func:`bounded_block_qp`;
- *verify* the step against the rig: every interior frame is evaluated at ``c + α d`` and the step is taken only
  when the objective computed from those evaluations decreases (α halved otherwise); each frame's Jacobian is
  then updated by Broyden's rank-one formula from the evaluated change (*re-linearised*) and the loop repeats.

The scale ``λ`` uses ``mean_f tr(ΣJ_fᵀJ_fΣ) / n`` of the first linearisation and the anchor ``c⁰_f`` is the ridge
fit (toward the rest controls ``r``) of that linearisation, ``r + Σ (ΣJ_fᵀJ_fΣ + λI)⁻¹ ΣJ_fᵀ (T_f − P_f +
J_f (c_f − r))``: on a linear rig (``J_f = B``, ``r = 0``) both are the shape-key route's, so the answer is the
shape-key space-time solver's (``tests/core/test_rig_spacetime.py``).  The take stops ``OK`` when the predicted
decrease of the last model is at most ``ftol`` of the objective (plus the objective's rounding when the points are
evaluated in a given ``precision``) or no point would move by more than ``xtol``;
``NOT_CONVERGED`` (the best controls found returned) when ``max_outer`` steps are used or a step verified
against the rig does not decrease the objective even when halved :data:`MAX_HALVINGS` times.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from numpy.typing import ArrayLike
from scipy.linalg import solveh_banded

from ..blas_threads import single_threaded
from ..errors import ErrorCode
from ..progress import ProgressFn, notify
from ..result import Result, ShapeSpaceError, Status
from .solve import broyden_update
from .take import RigTakeResult

__all__ = ["RigSpacetimeResult", "anchor_fit", "bounded_block_qp", "relative_lambda", "solve_take_spacetime",
           "take_result", "MAX_HALVINGS"]

#: Step halvings tried before a Gauss–Newton step that does not decrease the verified objective stops the take.
MAX_HALVINGS = 6
#: Semismooth-Newton (active-set) iterations of one bounded quadratic.
QP_MAX_ITER = 60


@dataclass(kw_only=True)
class RigSpacetimeResult(Result):
    """Outcome of :func:`solve_take_spacetime`: ``value`` the controls per frame (F, n);
    ``iterations`` the Gauss–Newton steps taken; ``diagnostics``: ``objective`` (verified, final),
    ``objective_start``, ``evaluations``, ``lam`` (absolute), ``qp_iterations``, ``rms`` (F,) per-frame RMS
    point distance of the evaluated rig."""

    @property
    def controls(self) -> np.ndarray:
        return self.value


def relative_lambda(J: np.ndarray, sigma: np.ndarray, lam: float) -> float:
    """``lam · mean_f tr(ΣJ_fᵀJ_fΣ) / n`` for Jacobians ``J`` (F, 3p, n) and scales ``sigma`` (n,) — the shape-key
    route's relative λ (mean eigenvalue of ``ΣBᵀBΣ``) when every ``J_f = B``."""
    n = J.shape[2]
    tr = float(np.einsum("fik,fik,k->", J, J, sigma * sigma, optimize=True)) / J.shape[0]
    return lam * max(tr / n, 1e-300)


def anchor_fit(J: np.ndarray, P: np.ndarray, C: np.ndarray, T: np.ndarray, rest: np.ndarray, sigma: np.ndarray,
               lam_abs: float) -> np.ndarray:
    """The per-frame ridge fits (F, n) toward ``rest`` on each frame's linearisation (module doc).

    Parameters
    ----------
    J : ndarray (F, 3p, n)
    P, T : ndarray (F, 3p)
        Points at ``C`` and targets.
    C : ndarray (F, n)
    rest : ndarray (n,)
    sigma : ndarray (n,)
    lam_abs : float
    """
    n = C.shape[1]
    Js = J * sigma
    E = T - P + np.matmul(J, (C - rest)[:, :, None])[:, :, 0]
    G = np.matmul(Js.transpose(0, 2, 1), Js) + lam_abs * np.eye(n)
    out = rest + sigma * np.linalg.solve(G, np.matmul(Js.transpose(0, 2, 1), E[:, :, None]))[:, :, 0]
    return out


class _BandPattern:
    """Where each entry of the block rows (N, n, 2n) — diagonal block then super-diagonal block — goes in LAPACK
    upper band storage (u = 2n − 1, frame-major), computed once per shape."""

    def __init__(self, N: int, n: int):
        t, k, m = np.indices((N, n, 2 * n))
        i, j = t * n + k, t * n + m
        self.keep = (j >= i) & (j < N * n)
        self.i, self.j = i[self.keep], j[self.keep]
        self.row = 2 * n - 1 + self.i - self.j
        self.diag = self.i == self.j
        self.shape = (2 * n, N * n)

    def band(self, Dg: np.ndarray, E: np.ndarray, held: np.ndarray) -> np.ndarray:
        """The band of the block-tridiagonal matrix (diagonal blocks ``Dg`` (N, n, n), super-diagonal blocks
        ``E`` (N − 1, n, n)), rows and columns ``held`` (N·n bool) replaced by the identity."""
        N, n = Dg.shape[:2]
        R = np.zeros((N, n, 2 * n))
        R[:, :, :n] = Dg
        R[:-1, :, n:] = E
        vals = R[self.keep]
        h = held.reshape(-1)
        hi, hj = h[self.i], h[self.j]
        vals[hi | hj] = 0.0
        vals[self.diag & hi] = 1.0
        ab = np.zeros(self.shape)
        ab[self.row, self.j] = vals
        return ab


def _apply(Dg: np.ndarray, E: np.ndarray, X: np.ndarray) -> np.ndarray:
    """The block-tridiagonal matrix times ``X`` (N, n)."""
    Y = np.einsum("tkl,tl->tk", Dg, X)
    Y[:-1] += np.einsum("tkl,tl->tk", E, X[1:])
    Y[1:] += np.einsum("tlk,tl->tk", E, X[:-1])
    return Y


def bounded_block_qp(Dg: np.ndarray, E: np.ndarray, g: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                     tol: float = 1e-12, max_iter: int = QP_MAX_ITER) -> tuple:
    """``argmin ½ xᵀHx + gᵀx, lo ≤ x ≤ hi`` for a symmetric positive definite block-tridiagonal ``H``.

    Semismooth Newton on the natural residual ``x − clip(x − κ(Hx + g))`` (κ = 1 / diag H): each iteration holds
    the entries whose projected gradient step leaves the box at that bound and solves exactly for the others
    (band Cholesky, the held rows and columns replaced by the identity).

    Parameters
    ----------
    Dg : ndarray (N, n, n)
        Diagonal blocks.
    E : ndarray (N − 1, n, n)
        Super-diagonal blocks ``H[t, t + 1]``.
    g : ndarray (N, n)
    lo, hi : ndarray (N, n)
        Bounds (``lo ≤ 0 ≤ hi`` is not required; infinite entries are free).
    tol : float
        Natural-residual tolerance relative to ``max(1, ‖g‖∞)``.
    max_iter : int

    Returns
    -------
    tuple
        ``(x (N, n), iterations, converged)``.
    """
    kappa = 1.0 / np.einsum("tkk->tk", Dg)
    pattern = _BandPattern(*g.shape)
    held = np.zeros(g.shape, dtype=bool)
    x = np.zeros_like(g)
    scale = max(1.0, float(np.abs(g).max()))
    seen = set()
    for it in range(1, max_iter + 1):
        fixed = np.where(held, x, 0.0)
        rhs = -g - _apply(Dg, E, fixed)
        rhs[held] = fixed[held]
        with single_threaded():          # one banded factor after another: BLAS threads only spin
            x = solveh_banded(pattern.band(Dg, E, held), rhs.reshape(-1), check_finite=False).reshape(g.shape)
        grad = _apply(Dg, E, x) + g
        y = x - kappa * grad
        nat = np.abs(x - np.clip(y, lo, hi)).max()
        if nat <= tol * scale:
            return np.clip(x, lo, hi), it, True
        low, high = y < lo, y > hi
        x = np.where(low, lo, np.where(high, hi, x))
        held = low | high
        key = held.tobytes() + low.tobytes()
        if key in seen:                                         # cycling: the last exact solve, clipped
            return np.clip(x, lo, hi), it, False
        seen.add(key)
    return np.clip(x, lo, hi), max_iter, False


def _objective(R: np.ndarray, C: np.ndarray, A: np.ndarray, sigma: np.ndarray, lam_abs: float) -> float:
    """½‖D R‖² + ½λ Σ_interior ‖(c − a)/σ‖² for residuals ``R`` (F, 3p) (points minus targets)."""
    V = np.diff(R, axis=0)
    Z = (C[1:-1] - A[1:-1]) / sigma
    return 0.5 * float(np.sum(V * V)) + 0.5 * lam_abs * float(np.sum(Z * Z))


def _model(J, R, C, A, sigma, lam_abs):
    """Blocks, gradient of the Gauss–Newton quadratic in the interior steps (module doc)."""
    Ji = J[1:-1]
    w = lam_abs / (sigma * sigma)
    JiT = Ji.transpose(0, 2, 1)
    Dg = 2.0 * np.matmul(JiT, Ji)
    Dg[:, np.arange(sigma.size), np.arange(sigma.size)] += w
    E = -np.matmul(JiT[:-1], Ji[1:])
    V = np.diff(R, axis=0)                                      # (F − 1, 3p): v_f = R_{f+1} − R_f
    g = np.matmul(JiT, (V[:-1] - V[1:])[:, :, None])[:, :, 0] + w * (C[1:-1] - A[1:-1])
    return Dg, E, g


def _check(C0, P0, J0, targets, sigma, lo, hi):
    C = np.array(C0, dtype=np.float64)
    F, n = C.shape if C.ndim == 2 else (0, 0)
    if F < 3:
        raise ShapeSpaceError(f"space-time needs a take of at least 3 frames, got {C.shape}", "too_short")
    T = np.asarray(targets, dtype=np.float64).reshape(F, -1)
    P = np.asarray(P0, dtype=np.float64).reshape(F, -1)
    J = np.array(J0, dtype=np.float64)
    if P.shape != T.shape or J.shape != (F, T.shape[1], n):
        raise ShapeSpaceError(f"points {P.shape}, Jacobians {J.shape} and targets {T.shape} do not match "
                              f"{F} frames of {n} controls", ErrorCode.SHAPE)
    if not (np.isfinite(T).all() and np.isfinite(P).all() and np.isfinite(J).all()):
        raise ShapeSpaceError("targets, points or Jacobians are not finite", ErrorCode.NON_FINITE)
    s = np.asarray(sigma, dtype=np.float64).reshape(-1)
    if s.shape != (n,) or not np.all(np.isfinite(s) & (s > 0)):
        raise ShapeSpaceError(f"sigma: expected {n} positive numbers", ErrorCode.RANGE)
    lo_ = np.broadcast_to(-np.inf if lo is None else np.asarray(lo, dtype=np.float64), (n,))
    hi_ = np.broadcast_to(np.inf if hi is None else np.asarray(hi, dtype=np.float64), (n,))
    return C, P, J, T, s, lo_, hi_


def solve_take_spacetime(evaluate: Callable, C0: ArrayLike, P0: ArrayLike, J0: ArrayLike | None,
                         targets: ArrayLike, sigma: ArrayLike, *, jacobian: Callable | None = None,
                         lo: ArrayLike | None = None, hi: ArrayLike | None = None,
                         rest: ArrayLike | None = None, lam: float = 1e-7, first: ArrayLike | None = None,
                         last: ArrayLike | None = None, max_outer: int = 8, ftol: float = 1e-8, xtol: float = 0.0,
                         precision: float = 0.0, progress: ProgressFn | None = None) -> RigSpacetimeResult:
    """Space-time controls of a take on any rig (module doc): Gauss–Newton on the whole take, each step verified.

    Parameters
    ----------
    evaluate : callable (n,) -> (p, 3)
        The rig's points for a control vector.
    C0 : array_like (F, n)
        Start (the per-frame pass; inside the bounds), F ≥ 3.
    P0 : array_like (F, p, 3)
        ``evaluate`` at each row of ``C0``.
    J0 : array_like (F, 3p, n) or None
        Jacobians there (fresh or Broyden-updated); ``None`` with ``jacobian``.
    targets : array_like (F, p, 3)
    sigma : array_like (n,)
        Per-control scales σ (the shape-key route's per-slider σ).
    jacobian : callable (n,), (p, 3) -> (3p, n), optional
        A fresh Jacobian: then every frame is linearised afresh at the start (Broyden-updated Jacobians of the
        per-frame pass drift with the evaluation's rounding) and again once when a verified step is refused.
    lo, hi : array_like (n,), optional
        Bounds.
    rest : array_like (n,), optional
        What the anchor's ridge pulls toward (zeros by default, as the shape-key route's weights).
    lam : float
        Relative λ (the retarget command's ``--lam``; module doc).
    first, last : array_like (n,), optional
        Held end frames (``C0[0]`` and ``C0[-1]`` by default).
    max_outer : int
        Gauss–Newton steps before ``NOT_CONVERGED``.
    ftol, xtol : float
        Stopping tests (module doc).
    precision : float
        Absolute precision of the evaluated points (Blender's float32 coordinates: ``2⁻²⁴ · max |P|``): a
        predicted decrease within the objective's rounding, ``2 · precision · Σ |D R|``, also stops ``OK``.
    progress : callable, optional
        ``progress(fraction)`` after each step; :class:`~core.progress.Cancelled` from it stops the solve.

    Returns
    -------
    RigSpacetimeResult
    """
    evals = 0
    if J0 is None:
        if jacobian is None:
            raise ShapeSpaceError("space-time needs the Jacobians or a jacobian function", ErrorCode.INVALID)
        Cs, Ps = np.asarray(C0, dtype=np.float64), np.asarray(P0, dtype=np.float64)
        J0 = np.stack([np.asarray(jacobian(c, p), dtype=np.float64) for c, p in zip(Cs, Ps)])
        evals += Cs.size
    C, P, J, T, sig, lo_, hi_ = _check(C0, P0, J0, targets, sigma, lo, hi)
    F, n = C.shape
    if not (np.isfinite(lam) and lam > 0):
        raise ShapeSpaceError(f"lam = {lam} must be a positive number", ErrorCode.RANGE)
    r = np.zeros(n) if rest is None else np.asarray(rest, dtype=np.float64).reshape(n)
    lam_abs = relative_lambda(J, sig, lam)
    with single_threaded():
        A = anchor_fit(J, P, C, T, r, sig, lam_abs)
    for row, given in ((0, first), (F - 1, last)):
        if given is not None:
            C[row] = np.clip(np.asarray(given, dtype=np.float64).reshape(n), lo_, hi_)
            P[row] = np.asarray(evaluate(C[row]), dtype=np.float64).reshape(-1)
            evals += 1
    phi0 = phi = _objective(P - T, C, A, sig, lam_abs)
    status, message, qp_its, steps, fresh = Status.NOT_CONVERGED, "", 0, 0, jacobian is not None
    notify(progress, 0.0)
    for _ in range(max_outer):
        with single_threaded():                 # many small products: BLAS threads only spin
            Dg, E, g = _model(J, P - T, C, A, sig, lam_abs)
        d, its, _ok = bounded_block_qp(Dg, E, g, lo_ - C[1:-1], hi_ - C[1:-1])
        qp_its += its
        pred = -(float(np.sum(g * d)) + 0.5 * float(np.sum(d * _apply(Dg, E, d))))
        move = float(np.abs(np.einsum("tik,tk->ti", J[1:-1], d)).max()) if d.size else 0.0
        noise = 2.0 * precision * float(np.abs(np.diff(P - T, axis=0)).sum())
        if pred <= ftol * max(phi, 1e-300) + noise or move <= xtol:
            status, message = Status.OK, f"converged after {steps} Gauss–Newton steps (objective {phi:.6g})"
            break
        alpha, accepted = 1.0, False
        for _h in range(MAX_HALVINGS + 1):
            Cn = C.copy()
            Cn[1:-1] = np.clip(C[1:-1] + alpha * d, lo_, hi_)
            Pn = P.copy()
            for f in range(1, F - 1):
                Pn[f] = np.asarray(evaluate(Cn[f]), dtype=np.float64).reshape(-1)
            evals += F - 2
            phin = _objective(Pn - T, Cn, A, sig, lam_abs)
            if phin < phi:
                accepted = True
                break
            alpha *= 0.5
        if not accepted and jacobian is not None and not fresh:   # re-linearise afresh, once
            J[1:-1] = np.stack([np.asarray(jacobian(c, p.reshape(-1, 3)), dtype=np.float64)
                                for c, p in zip(C[1:-1], P[1:-1])])
            evals += (F - 2) * n
            fresh = True
            continue
        if not accepted:
            message = (f"a Gauss–Newton step verified against the rig did not decrease the objective "
                       f"({phi:.6g}) after {MAX_HALVINGS} halvings")
            break
        fresh = False
        for f in range(1, F - 1):
            J[f] = broyden_update(J[f], Cn[f] - C[f], Pn[f] - P[f])
        C, P, phi = Cn, Pn, phin
        steps += 1
        notify(progress, steps / max_outer)
    else:
        message = f"stopped after {max_outer} Gauss–Newton steps (objective {phi:.6g})"
    notify(progress, 1.0)
    rms = np.sqrt(np.mean(((P - T) ** 2).reshape(F, -1, 3).sum(-1), axis=1))
    return RigSpacetimeResult(C, status=status, message=message, iterations=steps,
                              diagnostics={"objective": phi, "objective_start": phi0, "evaluations": evals,
                                           "lam": lam_abs, "qp_iterations": qp_its, "rms": rms,
                                           "points": P.reshape(F, -1, 3)})


def take_result(per_frame: RigTakeResult, result: RigSpacetimeResult, targets: ArrayLike) -> RigTakeResult:
    """The space-time answer as a :class:`~core.rig.take.RigTakeResult` (what :func:`core.rig.take.take_report`
    reads): its controls, status and message; per frame the rig's evaluated RMS and largest point distance (every
    frame ``OK``: frames are not solved one by one); evaluations of both passes; ``diagnostics['method']``
    ``'spacetime'`` and the verified objective before and after."""
    P = result.diagnostics["points"]
    t = np.asarray(targets, dtype=np.float64).reshape(P.shape)
    d = np.linalg.norm(P - t, axis=2)
    F = P.shape[0]
    return RigTakeResult(result.value, status=result.status, message=result.message, iterations=result.iterations,
                         frame_status=np.zeros(F, dtype=np.int64), rms=np.sqrt(np.mean(d * d, axis=1)),
                         pin_error_max=d.max(axis=1),
                         evaluations=per_frame.evaluations + result.diagnostics["evaluations"],
                         jacobians=per_frame.jacobians,
                         diagnostics={"method": "spacetime", "objective": result.diagnostics["objective"],
                                      "objective_start": result.diagnostics["objective_start"],
                                      "lam": result.diagnostics["lam"],
                                      "per_frame_status": int(per_frame.status)})
