"""The bounded methods: the held (active) set of ``min ½ yᵀ𝓗y − r₀ᵀy, ylo ≤ y ≤ yhi``, each step a kernel solve.

- :func:`clipped_solve` — one exact solve with every violated entry held (shallow violations only);
- :func:`peak_active_set` — hold the deepest entries of every run of violated frames (:func:`run_peaks`);
- :func:`interior_point` — Mehrotra predictor–corrector with an exact crossover (rank-deficient rigs);
- :func:`active_set` — the primal–dual active set (Hintermüller–Ito–Kunisch);
- :func:`projected_newton` — an ε-active set and a projected Armijo search (Bertsekas 1982), monotone.

Which to run, in what order, is :mod:`.solve`.
"""
from __future__ import annotations

import numpy as np

from ...progress import ProgressFn, notify
from ...result import Status
from .kernels import BlockCholesky, block_step, capacitance_limit, reduced_step
from .system import SpacetimeSystem

__all__ = ["clipped_solve", "peak_active_set", "interior_point", "active_set", "projected_newton", "run_peaks",
           "shallow_violation", "PEAK_PATIENCE", "PEAK_FRACTION", "SHALLOW_VIOLATION"]

#: Iterations :func:`peak_active_set` may go without lowering the best 2-norm of its natural residual by 10 %.
PEAK_PATIENCE = 5

#: :func:`peak_active_set` holds the entries of a violated run at least this fraction of the run's deepest violation
#: (1: the deepest entry alone).  A run's final held stretch is its deepest part, so holding the upper half at once
#: grows it geometrically: 36,000 frames onto FBHead settle in 3 exact solves instead of 13 (the deepest entry
#: alone), with the same KKT point (the natural-residual test decides either way).
PEAK_FRACTION = 0.5

#: :func:`clipped_solve` is tried first when no entry of the unbounded solution violates its bound by more than
#: this fraction of the slider's range (tiny dips below 0 where the source rests; never real clipping).
SHALLOW_VIOLATION = 1e-3


def run_peaks(v: np.ndarray, fraction: float = 1.0) -> np.ndarray:
    """The deepest entry of every run of consecutive positive entries along time, per channel (with
    ``fraction`` < 1: every entry of a run at least that fraction of the run's deepest).

    Parameters
    ----------
    v : ndarray (f − 2, n)
        Violation (> 0 where violated).
    fraction : float
        In (0, 1].

    Returns
    -------
    ndarray of bool (f − 2, n)
    """
    N, n = v.shape
    pos = np.zeros((n, N + 1), dtype=bool)
    pos[:, :N] = v.T > 0
    vals = np.zeros((n, N + 1))
    vals[:, :N] = v.T
    pos, vals = pos.ravel(), vals.ravel()
    idx = np.flatnonzero(pos)
    out = np.zeros(n * (N + 1), dtype=bool)
    if idx.size:
        starts = np.ones(idx.size, dtype=bool)
        starts[1:] = np.diff(idx) > 1
        run = np.cumsum(starts) - 1
        peak = np.maximum.reduceat(vals[idx], np.flatnonzero(starts))
        out[idx[vals[idx] >= fraction * peak[run]]] = True
    return out.reshape(n, N + 1)[:, :N].T


# ------------------------------------------------------------------ the bounded iteration
def _natural(Y: np.ndarray, mult: np.ndarray, ylo: np.ndarray, yhi: np.ndarray) -> float:
    """Natural residual ``‖y − clip(y − ∇f)‖∞`` (``mult = −∇f``); it also measures any bound violation."""
    return float(np.abs(Y - np.clip(Y + mult, ylo, yhi)).max(initial=0.0))


def shallow_violation(Y: np.ndarray, ylo: np.ndarray, yhi: np.ndarray) -> bool:
    """Whether the unbounded solution leaves its bounds, and only by a sliver: every violation within
    :data:`SHALLOW_VIOLATION` of the slider's range (σ-scaled), or of 1 where the range is unbounded."""
    width = np.where(np.isfinite(yhi - ylo), yhi - ylo, 1.0)
    depth = np.maximum(ylo - Y, Y - yhi)
    return bool(depth.max(initial=0.0) > 0.0 and np.all(depth <= SHALLOW_VIOLATION * width))


def clipped_solve(system: SpacetimeSystem, Y: np.ndarray, R0: np.ndarray, ylo: np.ndarray, yhi: np.ndarray,
                  tol: float, scale: float, progress: ProgressFn | None = None) -> tuple:
    """One exact solve with every violated entry of the unbounded solution held at its bound.

    On a take with nothing to clip, the unbounded solution still dips below a slider's 0 by a sliver
    wherever the source rests at 0 (the per-frame ridge fit it is anchored to mixes keys): 357,000 entries
    by at most 1e-4 on 36,000 frames onto ICT FaceKit.  Holding them all is then already the KKT point to
    the tolerance — the held entries whose multiplier has the wrong sign are held by a multiplier as small as
    their violation — where growing the active set from run peaks (:func:`peak_active_set`) needs a
    factorisation per pass over hundreds of thousands of runs.  Used only for a :func:`shallow_violation`
    (deep clipping makes most held entries wrong; the peak iteration is the route there).

    Returns
    -------
    Y : ndarray (f − 2, n)
    converged : bool
        Whether the natural residual meets ``tol · scale``.
    start : tuple or None
        ``(lower, upper, factor)``: the held sets and their :class:`BlockCholesky`, from which
        :func:`peak_active_set` goes on when the solve did not converge (36,000 frames onto FBHead: 2 more
        solves instead of 3 from the unbounded solution, and the factor's memory taken over); ``None`` when the
        factorisation failed (the caller starts over from the unbounded solution).
    """
    upper, lower = Y > yhi, Y < ylo
    Yh = np.where(upper, yhi, np.where(lower, ylo, Y))
    try:
        factor = BlockCholesky(system, upper | lower, progress=progress)
    except np.linalg.LinAlgError:
        return Y, False, None
    system.solves += 1
    Yn = Yh + factor.solve(R0 - system.apply(Yh))
    return Yn, _natural(Yn, R0 - system.apply(Yn), ylo, yhi) <= tol * scale, (lower, upper, factor)


def peak_active_set(system: SpacetimeSystem, Y: np.ndarray, R0: np.ndarray, ylo: np.ndarray, yhi: np.ndarray,
                    tol: float, max_iter: int, scale: float, progress: ProgressFn | None = None,
                    start: tuple | None = None) -> tuple:
    """Active set grown from below: hold the deepest entries of every violated run, free wrong-signed holds.

    From the unbounded solution, each iteration holds (at its bound) the most
    violated entries of every run of consecutive violated frames of a slider (those violated by at
    least :data:`PEAK_FRACTION` of the run's deepest),
    releases held entries whose multiplier has the wrong sign, and solves
    exactly for the rest (:class:`BlockCholesky`).  Holding a run's deepest
    point lifts its neighbours through the time coupling, so the held set
    grows towards the optimal active set without the overshoot of holding
    every violated entry (a fraction of which ends up active on real takes).
    Each solve takes the cheaper exact route for the held set's size
    (:func:`capacitance_limit`: capacitance while few are held, else the block
    Cholesky, which keeps the blocks of the frames before the first change
    from the previous iteration).
    Stops at the natural-residual tolerance, or when the held set repeats
    (cycling) or the 2-norm of the natural residual (over the whole take: its
    max-norm plateaus on long takes while distant runs are being settled) has
    not dropped below 0.9 of its best for :data:`PEAK_PATIENCE` iterations (the
    caller globalises).

    Parameters
    ----------
    system : SpacetimeSystem
    Y : ndarray (f − 2, n)
        The unbounded solution (with ``start``: the exact solution for its held sets).
    R0, ylo, yhi : ndarray (f − 2, n)
    tol, scale : float
    max_iter : int
    progress : callable, optional
        Called with the iteration's fraction of ``max_iter``.
    start : tuple, optional
        ``(lower, upper, factor)``: held sets to go on from (nothing held by default) and their
        :class:`BlockCholesky` (or ``None``), as :func:`clipped_solve` returns them.

    Returns
    -------
    Y : ndarray (f − 2, n)
        The last iterate (exact for its held set; may violate the bounds when not converged).
    iterations : int
    converged : bool
    """
    lower, upper, factor = start or (np.zeros(Y.shape, dtype=bool), np.zeros(Y.shape, dtype=bool), None)
    seen = set()
    best, since = np.inf, 0
    limit = capacitance_limit(system)
    for it in range(max_iter + 1):
        notify(progress, it / max_iter)
        mult = R0 - system.apply(Y)
        nat = _natural(Y, mult, ylo, yhi)
        if nat <= tol * scale:
            return Y, it, True
        total = float(np.linalg.norm(Y - np.clip(Y + mult, ylo, yhi)))    # progress over the whole take
        best, since = (total, 0) if total < 0.9 * best else (best, since + 1)
        if it == max_iter or since >= PEAK_PATIENCE:
            break                                                   # no progress: the caller globalises
        held = lower | upper
        thr = 1e-3 * tol * scale
        add_lo = run_peaks(np.where(held, 0.0, ylo - Y - thr), PEAK_FRACTION)
        add_hi = run_peaks(np.where(held, 0.0, Y - yhi - thr), PEAK_FRACTION)
        new_lower = (lower & ~(mult > 0)) | add_lo
        new_upper = (upper & ~(mult < 0)) | add_hi
        key = hash(np.packbits(new_lower).tobytes() + np.packbits(new_upper).tobytes())
        if key in seen or (np.array_equal(new_lower, lower) and np.array_equal(new_upper, upper)):
            break                                                   # cycling (or rounding): globalise
        seen.add(key)
        lower, upper = new_lower, new_upper
        held = lower | upper
        Yh = np.where(upper, yhi, np.where(lower, ylo, Y))
        r = R0 - system.apply(Yh)
        if held.sum() > limit:                                      # block Cholesky, reusing the unchanged prefix
            try:
                factor = BlockCholesky(system, held, previous=factor)
                system.solves += 1
                Y = Yh + factor.solve(r)
                continue
            except np.linalg.LinAlgError:
                factor = None
        Y = Yh + reduced_step(system, held, r, scale, limit)
    return Y, it, False


def interior_point(system: SpacetimeSystem, Y: np.ndarray, R0: np.ndarray, ylo: np.ndarray, yhi: np.ndarray,
                   tol: float, max_iter: int, scale: float, progress: ProgressFn | None = None) -> tuple:
    """Primal–dual interior point (Mehrotra predictor–corrector) to a small complementarity gap.

    The robust route for degenerate problems (redundant rigs: duplicate keys
    make ``M`` singular, active-set iterations can cycle).  Each iteration
    factors ``𝓗 + Z_l S_l⁻¹ + Z_u S_u⁻¹`` once (:class:`BlockCholesky`) for the
    predictor and the corrector.  Stops when the mean complementarity gap and
    the dual residual are below ``10⁻² · tol · scale`` and the clipped point
    passes the natural-residual test; then the entries with ``s < z`` are
    held at their bounds and the rest solved for exactly, and that point
    returned if it passes too (:func:`_crossover`).  The caller checks the
    result with :func:`projected_newton`.

    Parameters
    ----------
    system : SpacetimeSystem
    Y : ndarray (f − 2, n)
        Start (any point; moved inside the box).
    R0, ylo, yhi : ndarray (f − 2, n)
        Right-hand side and whitened bounds (``ylo < yhi`` where finite; fixed entries are handled by the caller).
    tol, scale : float
    max_iter : int
    progress : callable, optional

    Returns
    -------
    Y : ndarray (f − 2, n)
    iterations : int
    converged : bool
        Whether the gap test was met.
    """
    fl, fu = np.isfinite(ylo), np.isfinite(yhi)
    lo_, hi_ = np.where(fl, ylo, 0.0), np.where(fu, yhi, 0.0)
    width = np.where(fl & fu, hi_ - lo_, 1.0 + np.abs(Y))
    y = np.clip(Y, np.where(fl, lo_ + 0.05 * width, -np.inf), np.where(fu, hi_ - 0.05 * width, np.inf))
    g0 = system.apply(y) - R0
    z0 = max(1e-8 * scale, float(np.abs(g0).mean()))
    zl, zu = np.where(fl, z0, 0.0), np.where(fu, z0, 0.0)
    count = max(1, int(fl.sum() + fu.sum()))
    for it in range(1, max_iter + 1):
        notify(progress, it / max_iter)
        sl, su = np.where(fl, y - lo_, 1.0), np.where(fu, hi_ - y, 1.0)
        rd = system.apply(y) - R0 - zl + zu
        mu = float(np.sum(sl * zl) + np.sum(su * zu)) / count
        if mu <= 1e-2 * tol * scale and float(np.abs(rd).max()) <= 1e-2 * tol * scale:
            yc = np.clip(y, ylo, yhi)
            nat = _natural(yc, R0 - system.apply(yc), ylo, yhi)
            if nat <= tol * scale:
                return _crossover(system, yc, R0, ylo, yhi, fl & (sl < zl), fu & (su < zu), nat), it, True
        dl, du = zl / sl, zu / su
        try:
            factor = BlockCholesky(system, shift=dl + du)
        except np.linalg.LinAlgError:
            return np.clip(y, ylo, yhi), it, False
        system.solves += 1
        dy = factor.solve(-rd - zl + zu)                               # predictor (affine scaling)
        dzl, dzu = -zl - dl * dy, -zu + du * dy
        alpha = _step_to_boundary(sl, su, zl, zu, dy, dzl, dzu, fl, fu, 1.0)
        mu_aff = float(np.sum((sl + alpha * dy) * (zl + alpha * dzl) * fl)
                       + np.sum((su - alpha * dy) * (zu + alpha * dzu) * fu)) / count
        sigma_mu = (mu_aff / mu) ** 3 * mu
        cl, cu = dy * dzl * fl, -dy * dzu * fu
        rhs = -rd + np.where(fl, (sigma_mu - cl) / sl, 0.0) - zl - np.where(fu, (sigma_mu - cu) / su, 0.0) + zu
        dy = factor.solve(rhs)                                        # corrector
        dzl = np.where(fl, (sigma_mu - sl * zl - cl - zl * dy) / sl, 0.0)
        dzu = np.where(fu, (sigma_mu - su * zu - cu + zu * dy) / su, 0.0)
        alpha = _step_to_boundary(sl, su, zl, zu, dy, dzl, dzu, fl, fu, 0.995)
        y, zl, zu = y + alpha * dy, zl + alpha * dzl, zu + alpha * dzu
    return np.clip(y, ylo, yhi), max_iter, False


def _crossover(system: SpacetimeSystem, y: np.ndarray, R0: np.ndarray, ylo: np.ndarray, yhi: np.ndarray,
               held_lo: np.ndarray, held_hi: np.ndarray, nat: float) -> np.ndarray:
    """The exact solution with the barrier's active set held, if its natural residual is no worse than ``nat``.

    In directions only λ curves (duplicate keys) the interior point's answer can be accurate to the KKT test yet
    off by ``nat / λ``; the exact solve on the right active set removes that.  (On a wrong set it is rejected.)
    """
    Yh = np.where(held_hi, yhi, np.where(held_lo, ylo, y))
    try:
        Yx = Yh + block_step(system, held_lo | held_hi, R0 - system.apply(Yh))
    except np.linalg.LinAlgError:
        return y
    return Yx if _natural(Yx, R0 - system.apply(Yx), ylo, yhi) <= nat else y


def _step_to_boundary(sl, su, zl, zu, dy, dzl, dzu, fl, fu, frac: float) -> float:
    """Largest step ≤ 1 keeping the slacks and multipliers positive, times ``frac``."""
    ratios = [1.0 / frac]
    for s, ds, mask in ((sl, dy, fl), (su, -dy, fu), (zl, dzl, fl), (zu, dzu, fu)):
        neg = mask & (ds < 0)
        if neg.any():
            ratios.append(float(np.min(-s[neg] / ds[neg])))
    return min(1.0, frac * min(ratios))


def active_set(system: SpacetimeSystem, Y: np.ndarray, R0: np.ndarray, ylo: np.ndarray, yhi: np.ndarray,
               max_iter: int, scale: float, max_exact_active: int) -> tuple:
    """Primal–dual active set (Hintermüller–Ito–Kunisch) from a point within the bounds.

    Fix the entries whose bound is active or violated, solve exactly for the
    rest (:func:`reduced_step`) and repeat with the multipliers' signs until
    the active set repeats — then the KKT conditions hold exactly.  Usually a
    handful of reduced solves; stops early on cycling (the caller globalises).

    Parameters
    ----------
    system : SpacetimeSystem
    Y : ndarray (f − 2, n)
        Start, within ``[ylo, yhi]`` (whitened).
    R0 : ndarray (f − 2, n)
        Right-hand side (:meth:`SpacetimeSystem.rhs`).
    ylo, yhi : ndarray (f − 2, n)
        Whitened bounds.
    max_iter : int
    scale : float
    max_exact_active : int

    Returns
    -------
    Y : ndarray (f − 2, n)
        The last iterate (not clipped).
    iterations : int
    """
    upper, lower = Y >= yhi, Y <= ylo
    seen = set()
    it = 0
    for it in range(1, max_iter + 1):  # noqa: B007 — the count is read after the loop
        Yn = np.where(upper, yhi, np.where(lower, ylo, Y))
        act = upper | lower
        Yn = Yn + reduced_step(system, act, R0 - system.apply(Yn), scale, max_exact_active)
        mult = R0 - system.apply(Yn)                             # −∇f: > 0 pushes up, < 0 pushes down
        new_upper = np.where(act, upper & (mult > 0), Yn > yhi)
        new_lower = np.where(act, lower & (mult < 0), Yn < ylo)
        Y = Yn
        if np.array_equal(new_upper, upper) and np.array_equal(new_lower, lower):
            break
        key = hash(np.packbits(new_upper).tobytes() + np.packbits(new_lower).tobytes())
        if key in seen:
            break                                                # cycling: globalise
        seen.add(key)
        upper, lower = new_upper, new_lower
    return Y, it


def projected_newton(system: SpacetimeSystem, Y: np.ndarray, R0: np.ndarray, ylo: np.ndarray, yhi: np.ndarray,
                     tol: float, max_iter: int, scale: float, max_exact_active: int) -> tuple:
    """Projected Newton with an ε-active set (Bertsekas 1982) and a projected Armijo search (monotone).

    Checks the natural residual ``‖y − clip(y − ∇f)‖∞ ≤ tol · scale`` first, so
    from the active-set method's exact point it returns at once.

    Parameters
    ----------
    system : SpacetimeSystem
    Y : ndarray (f − 2, n)
        Start, within the bounds.
    R0, ylo, yhi : ndarray (f − 2, n)
    tol : float
    max_iter : int
    scale : float
    max_exact_active : int

    Returns
    -------
    Y : ndarray (f − 2, n)
    iterations : int
        Newton iterations taken.
    status : Status
    message : str
    natural_residual : float
    """
    f = system.objective(Y, R0)
    status, message = Status.NOT_CONVERGED, "iteration limit reached"
    it = 0
    for it in range(1, max_iter + 1):  # noqa: B007 — the count is read after the loop
        g = system.apply(Y) - R0
        nat = float(np.abs(Y - np.clip(Y - g, ylo, yhi)).max())
        if nat <= tol * scale:
            status, message = Status.OK, "converged"
            break
        eps = min(1e-3, nat)
        act = ((Y <= ylo + eps) & (g > 0)) | ((Y >= yhi - eps) & (g < 0))
        d = reduced_step(system, act, np.where(~act, -g, 0.0), scale, max_exact_active)
        d = np.where(act, -g / (4.0 * float(system.mu.max()) * (1.0 + 0.25 * system.beta) + system.lam), d)
        step = 1.0
        while True:
            Yt = np.clip(Y + step * d, ylo, yhi)
            ft = system.objective(Yt, R0)
            if ft <= f - 1e-4 * float(np.sum(g * (Y - Yt))) or step < 1e-10:
                break
            step *= 0.5
        if ft >= f:
            if nat <= 1e-6 * scale:
                status, message = Status.OK, "converged (rounding limit)"
            else:
                status, message = Status.NOT_CONVERGED, "stalled"
            break
        Y, f = Yt, ft
    return Y, it - 1, status, message, nat
