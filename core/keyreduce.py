"""Key reduction (thesis 3.5.5): a dense curve (one sample per frame) into the fewest keys whose curve
stays within a max-error tolerance of every sample.

- :func:`reduce_keys` — linear keys, a subset of the samples (exact dynamic
  programming over valid segments);
- :func:`reduce_keys_bezier` — smooth Bézier keys with aligned handles: exact
  dynamic programming over sample subsets keeping the dense curve's slope
  (:func:`curve_slopes`), then a refinement that refits neighbours to absorb
  keys; :func:`hermite` is the cubic Hermite Blender evaluates for such keys.
  :func:`reduce_keys_bezier_curves` does the same for many curves at once,
  vectorised over them (an action's curves: ~20× faster than one by one),
  in time and memory linear in the number of samples, a long take's curves
  spread over the CPUs (threads, and child processes for the Python-bound
  second stage, :mod:`core.workers`) with the same keys.

Sampling keyed curves and frame-rate conversion are :mod:`core.animation`.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numpy.typing import ArrayLike
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import breadth_first_order

from .blas_threads import single_threaded
from .progress import ProgressFn, notify, scaled
from .result import ShapeSpaceError
from .validate import array, non_negative
from .workers import ChildCall, child_cpus

__all__ = ["reduce_keys", "reduce_keys_bezier", "reduce_keys_bezier_curves", "curve_slopes", "hermite", "chebyshev_fit"]


def _check_curve(times: ArrayLike, values: ArrayLike, tol: float) -> tuple:
    """Validated (times, values) as float64 (f,) and a non-negative tolerance."""
    t = array(times, "times").ravel()
    v = array(values, "values").ravel()
    if t.size != v.size or t.size < 1:
        raise ShapeSpaceError(f"times and values must be non-empty and of equal length, got {t.size} times and "
                              f"{v.size} values", "shape")
    non_negative(tol, "tol")
    return t, v


def _shortest_path(prev: np.ndarray) -> list:
    """Indices on the path ending at the last sample, following ``prev`` back to sample 0."""
    keep = [prev.size - 1]
    while keep[-1] != 0:
        keep.append(int(prev[keep[-1]]))
    return keep[::-1]


def reduce_keys(times: ArrayLike, values: ArrayLike, tol: float) -> np.ndarray:
    """Fewest keys (a subset of the samples) whose linear interpolation stays within ``tol`` (3.5.5).

    Exact dynamic programming (a shortest path over valid segments); a
    segment i→j is valid when the line through samples i and j is within
    ``tol`` of every sample between, tested in O(1) per step by narrowing the
    feasible slope interval from i.  Endpoints are always kept.

    Parameters
    ----------
    times : array_like, shape (f,)
        Increasing sample times.
    values : array_like, shape (f,)
    tol : float
        Max absolute error allowed at every sample (≥ 0).

    Returns
    -------
    ndarray of int, shape (k,)
        Indices of the kept samples (both ends always).
    """
    t, v = _check_curve(times, values, tol)
    n = t.size
    if n <= 2:
        return np.arange(n)
    best = np.full(n, np.iinfo(np.int64).max)
    prev = np.full(n, -1)
    best[0] = 1
    for i in range(n - 1):
        if best[i] == np.iinfo(np.int64).max:
            continue
        smin, smax = -np.inf, np.inf
        for j in range(i + 1, n):
            dt = t[j] - t[i]
            slope = (v[j] - v[i]) / dt
            if smin - 1e-15 <= slope <= smax + 1e-15 and best[i] + 1 < best[j]:
                best[j] = best[i] + 1
                prev[j] = i
            smin = max(smin, (v[j] - tol - v[i]) / dt)
            smax = min(smax, (v[j] + tol - v[i]) / dt)
            if smin > smax + 1e-15:
                break
    return np.array(_shortest_path(prev))


def curve_slopes(times: ArrayLike, values: ArrayLike) -> np.ndarray:
    """Slope of the dense curve at every sample.

    The derivative of the parabola through each sample and its two
    neighbours, ``m_i = (h₁ d₀ + h₀ d₁) / (h₀ + h₁)`` with ``h`` the two time
    steps and ``d`` the two secant slopes (one-sided secants at the ends).

    Parameters
    ----------
    times, values : array_like, shape (f,)

    Returns
    -------
    ndarray, shape (f,)
        Value units per time unit.
    """
    t = np.asarray(times, dtype=np.float64)
    v = np.asarray(values, dtype=np.float64)
    if t.size < 2:
        return np.zeros(t.size)
    m = np.empty(t.size)
    h0, h1 = t[1:-1] - t[:-2], t[2:] - t[1:-1]
    d0, d1 = (v[1:-1] - v[:-2]) / h0, (v[2:] - v[1:-1]) / h1
    m[1:-1] = (h1 * d0 + h0 * d1) / (h0 + h1)
    m[0] = (v[1] - v[0]) / (t[1] - t[0])
    m[-1] = (v[-1] - v[-2]) / (t[-1] - t[-2])
    return m


def hermite(times: ArrayLike, values: ArrayLike, slopes: ArrayLike, t: ArrayLike) -> np.ndarray:
    """Piecewise cubic Hermite through keys ``(times, values)`` with ``slopes``, evaluated at ``t``.

    Exactly what Blender evaluates for Bézier keys whose handles sit at a third
    of each segment along the slope:
    ``x(s) = h₀₀(s) v₀ + h₁₀(s) h m₀ + h₀₁(s) v₁ + h₁₁(s) h m₁`` on each segment
    of length ``h``, ``s ∈ [0, 1]``.

    Parameters
    ----------
    times, values, slopes : array_like, shape (k,)
        Keys (times increasing).
    t : array_like, shape (q,)
        Where to evaluate.

    Returns
    -------
    ndarray, shape (q,)
    """
    kt, kv, km = (np.asarray(a, dtype=np.float64) for a in (times, values, slopes))
    t = np.asarray(t, dtype=np.float64)
    seg = np.clip(np.searchsorted(kt, t, side="right") - 1, 0, max(kt.size - 2, 0))
    if kt.size == 1:
        return np.full(t.shape, kv[0])
    h = kt[seg + 1] - kt[seg]
    s = (t - kt[seg]) / h
    h00, h10 = (1 + 2 * s) * (1 - s) ** 2, s * (1 - s) ** 2
    h01, h11 = s * s * (3 - 2 * s), s * s * (s - 1)
    return h00 * kv[seg] + h10 * h * km[seg] + h01 * kv[seg + 1] + h11 * h * km[seg + 1]


def _segment_basis(t0: float, t1: float, ts: np.ndarray) -> np.ndarray:
    """Hermite basis on [t0, t1] at ``ts``: columns multiply (v0, m0, v1, m1), shape (len(ts), 4)."""
    h = t1 - t0
    s = (ts - t0) / h
    return np.column_stack([(1 + 2 * s) * (1 - s) ** 2, h * s * (1 - s) ** 2, s * s * (3 - 2 * s),
                            h * s * s * (s - 1)])


def _fit_two_keys(A: np.ndarray, y: np.ndarray) -> tuple:
    """Least-squares values and slopes of two keys, with the max error ``‖A x − y‖∞`` they leave."""
    x = np.linalg.lstsq(A, y, rcond=None)[0]
    return x, float(np.abs(A @ x - y).max())


def _chebyshev_start(A: np.ndarray, y: np.ndarray) -> tuple:
    """First reference of :func:`chebyshev_fit`: k independent rows (pivoted QR) plus the worst row of the
    least-squares fit, with signs and dual weights from the null vector of their k × (k + 1) transpose."""
    from scipy.linalg import qr
    k = A.shape[1]
    rows = [int(r) for r in qr(A.T, mode="r", pivoting=True)[1][:k]]
    r0 = np.abs(A @ np.linalg.lstsq(A, y, rcond=None)[0] - y)
    r0[rows] = -1.0
    rows.append(int(np.argmax(r0)))
    u = np.ones(k + 1)
    u[:k] = -np.linalg.solve(A[rows[:k]].T, A[rows[k]])
    return np.array(rows), np.where(u < 0, -1.0, 1.0), np.abs(u) / np.abs(u).sum()


def chebyshev_fit(A: ArrayLike, y: ArrayLike, stop_above: float = np.inf, max_iter: int = 500) -> tuple:
    """Discrete Chebyshev (minimax) fit ``min_x ‖A x − y‖∞`` by the exchange algorithm (Stiefel).

    The dual of the linear program ``min t  s.t.  −t ≤ A x − y ≤ t`` is
    ``max yᵀu  s.t.  Aᵀu = 0, ‖u‖₁ ≤ 1``, whose basic solutions are
    references of k + 1 rows S with signs σ.  On a reference the levelled
    fit solves ``σᵢ (yᵢ − aᵢᵀx) = h`` (i ∈ S), a (k+1) × (k+1) system; the
    row with the largest residual enters if it exceeds h, the ratio test on
    the dual weights picks the row that leaves (a simplex step, so
    non-Haar systems are fine), and h increases monotonically to the
    optimum.  Each h is a lower bound of the optimum, so a caller who only
    needs to know whether the optimum is ≤ a tolerance can stop early
    (``stop_above``).  Rank-deficient A is reduced to a column basis
    (pivoted QR) first.  Same optimum as ``scipy.optimize.linprog`` on the
    linear program, at a few small solves instead of a general LP solver.

    Parameters
    ----------
    A : array_like, shape (m, k)
    y : array_like, shape (m,)
    stop_above : float
        Return as soon as the lower bound h exceeds this (``x`` is then None).
    max_iter : int
        Exchange steps before giving up (degenerate cycling; ``x`` None, error inf; also on a singular
        reference).

    Returns
    -------
    x : ndarray (k,) or None
    err : float
        ``‖A x − y‖∞`` at the optimum, or the lower bound that exceeded ``stop_above``.
    """
    from scipy.linalg import qr
    A = np.asarray(A, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    x = np.zeros(A.shape[1])
    if y.size == 0:
        return x, 0.0
    _, R, piv = qr(A, mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    k = int((d > 1e-12 * d[0]).sum()) if d.size and d[0] > 0 else 0
    if k == 0 or k >= y.size:
        x[piv[:k]] = np.linalg.lstsq(A[:, piv[:k]], y, rcond=None)[0] if k else 0.0
        return x, float(np.abs(A @ x - y).max())
    cols = piv[:k]
    Ar = A[:, cols]
    try:
        return _exchange(Ar, y, cols, x, stop_above, max_iter)
    except np.linalg.LinAlgError:                                    # a singular reference: no answer
        return None, np.inf


def _exchange(Ar: np.ndarray, y: np.ndarray, cols: np.ndarray, x: np.ndarray, stop_above: float,
              max_iter: int) -> tuple:
    """:func:`chebyshev_fit`'s exchange steps on the full-rank columns ``Ar`` (into ``x`` at ``cols``)."""
    k = Ar.shape[1]
    S, sigma, w = _chebyshev_start(Ar, y)
    scale = float(np.abs(y).max())
    last = np.ones(k + 1)
    for _ in range(max_iter):
        Mm = np.vstack([(Ar[S] * sigma[:, None]).T, last])
        pi = np.linalg.solve(Mm.T, sigma * y[S])
        xr, h = pi[:k], pi[k]
        if h > stop_above:
            return None, float(h)
        res = y - Ar @ xr
        j = int(np.argmax(np.abs(res)))
        if abs(res[j]) <= h + 1e-13 * scale:
            x[cols] = xr
            return x, float(np.abs(res).max())
        tau = 1.0 if res[j] > 0 else -1.0
        dd = np.linalg.solve(Mm, np.r_[tau * Ar[j], 1.0])
        pos = dd > 1e-14
        ratios = np.where(pos, w / np.where(pos, dd, 1.0), np.inf)
        leave = int(np.argmin(ratios))
        w = w - ratios[leave] * dd
        w[leave] = ratios[leave]
        S[leave], sigma[leave] = j, tau
    return None, np.inf


#: Longest stage-1 segment searched by default, in samples.  A shorter search (32) makes stage 1 four times
#: cheaper but leaves held poses in many keys, and stage 2 absorbing them one by one into ever longer segments
#: costs far more (2.5× the whole reduction on the 36,000-frame take).  Held poses, exactly or within
#: ``tol`` · :data:`_HELD_STEP` per step, are one segment at any length (:func:`_held_spans`), but noisier ones
#: are not: 10 curves of the take plus noise of 1e-4 take 8× longer at span 32 than at 128.
_MAX_SPAN = 128
#: Curves × samples processed together by :func:`reduce_keys_bezier_curves` (bounds its memory for long takes).
_BLOCK_SAMPLES = 1 << 18
#: Largest evaluation block (candidate segments × samples) in stage 1.
_EVAL_BLOCK = 1 << 20


def _hermite_basis(s: np.ndarray) -> tuple:
    """The four cubic Hermite basis functions at ``s`` (any shape): h₀₀, h₁₀, h₀₁, h₁₁."""
    u = 1.0 - s
    return (1 + 2 * s) * u * u, s * u * u, s * s * (3 - 2 * s), s * s * (s - 1)


def _span_fails(t: np.ndarray, V: np.ndarray, M: np.ndarray, c: np.ndarray, i: np.ndarray, d: int,
                e: np.ndarray, tol: float, uniform: bool) -> np.ndarray:
    """``True`` where the Hermite of curve ``c`` from sample i to i + d is more than ``tol`` off at a sample
    i + e (e (E,) interior offsets), shape (len(i),).  Blocks of candidates bound the memory."""
    n = V.shape[1]
    flat = V.ravel()
    out = np.empty(i.size, dtype=bool)
    step = max(1, _EVAL_BLOCK // max(e.size, 1))
    if uniform:
        H = np.column_stack(_hermite_basis(e / d))                     # (E, 4), same for every segment
    for lo in range(0, i.size, step):
        ci, ii = c[lo:lo + step], i[lo:lo + step]
        h = t[ii + d] - t[ii]
        base = ci * n + ii
        P = np.column_stack([flat[base], h * M.ravel()[base], flat[base + d], h * M.ravel()[base + d]])
        if uniform:
            curve = P @ H.T
        else:
            h00, h10, h01, h11 = _hermite_basis((t[ii[:, None] + e] - t[ii][:, None]) / h[:, None])
            curve = h00 * P[:, :1] + h10 * P[:, 1:2] + h01 * P[:, 2:3] + h11 * P[:, 3:]
        curve -= flat[base[:, None] + e]
        out[lo:lo + step] = np.abs(curve).max(axis=1) > tol
    return out


#: Starts per chunk of stage 1 (:func:`_valid_segments`).  With the starts that can no longer have a valid
#: segment dropped as the span grows (:func:`_valid_window_uniform`), 16,384 starts of a block's curves measured
#: fastest (4,096 kept the temporaries in cache but paid NumPy's per-call overhead on shrinking arrays).
_CHUNK_STARTS = 16384


def _valid_segments(t: np.ndarray, V: np.ndarray, M: np.ndarray, tol: float, max_span: int) -> np.ndarray:
    """Stage 1's valid segments of every curve, ``ok[c, i, d]`` shape (c, f, min(max_span, f − 1) + 1): the
    Hermite of curve c (row of ``V`` (c, f), slopes ``M``) from sample i to i + d stays within ``tol`` of every
    sample between.  Computed in chunks of :data:`_CHUNK_STARTS` starts (:func:`_valid_window`: the same
    arithmetic for every segment, in cache-sized pieces)."""
    C, n = V.shape
    span = min(max_span, n - 1)
    dt = np.diff(t)
    uniform = bool(np.all(np.abs(dt - dt[0]) <= 1e-12 * abs(dt[0])))
    if n <= _CHUNK_STARTS + span:
        return _valid_window(t, V, M, tol, span, uniform)
    valid = np.zeros((C, n, span + 1), dtype=bool)
    for lo in range(0, n - 1, _CHUNK_STARTS):
        hi = min(lo + _CHUNK_STARTS + span, n)
        w = min(_CHUNK_STARTS, n - lo)
        valid[:, lo:lo + w] = _valid_window(t[lo:hi], V[:, lo:hi], M[:, lo:hi], tol, span, uniform, w)
    return valid


def _valid_window(t: np.ndarray, V: np.ndarray, M: np.ndarray, tol: float, span: int, uniform: bool,
                  starts: int | None = None) -> np.ndarray:
    """:func:`_valid_segments` on the samples of ``t`` (f,) (spans up to ``span``; ``uniform`` time steps) for
    the first ``starts`` starts (all by default), shape (c, starts or f, span + 1).

    Vectorised over curves and starts for each span d (slices, no gathers).  A segment is accepted at once
    when a bound proves it (the curve stays in the end values' range widened by 4/27 · h · (|m_i| + |m_j|), so
    it is valid when the samples' range widened by that is ≤ tol); spans up to 12 are then evaluated at every
    interior sample, longer ones at their middle sample, and the survivors (gathered) on 4, every 8th, then
    all interior samples (failing anywhere is failing).  Exactly the segments whose max error is ≤ tol."""
    if uniform:
        return _valid_window_uniform(t, np.ascontiguousarray(V), np.ascontiguousarray(M), tol, span, starts)
    C, n = V.shape
    top, bottom = V.copy(), V.copy()                                  # range of the samples in [i, i + d]
    valid = np.zeros((C, n, span + 1), dtype=bool)
    for d in range(1, min(span, n - 1) + 1):
        w = n - d
        np.maximum(top[:, :w], V[:, d:], out=top[:, :w])
        np.minimum(bottom[:, :w], V[:, d:], out=bottom[:, :w])
        if d == 1:                                                    # no sample between: always valid
            ok = np.ones((C, w), dtype=bool)
        else:
            h = t[d:] - t[:w]
            Vi, Vj, hMi, hMj = V[:, :w], V[:, d:], h * M[:, :w], h * M[:, d:]
            ok = top[:, :w] - bottom[:, :w] + 4.0 / 27.0 * (np.abs(hMi) + np.abs(hMj)) <= tol
            err = np.zeros((C, w))
            for e in range(1, d) if d <= 12 else (d // 2,):           # short spans whole, long ones at the middle
                h00, h10, h01, h11 = _hermite_basis((t[e:e + w] - t[:w]) / h)
                np.maximum(err, np.abs(h00 * Vi + h10 * hMi + h01 * Vj + h11 * hMj - V[:, e:e + w]), out=err)
            if d <= 12:
                ok |= err <= tol
            else:
                c, i = np.nonzero(~ok & (err <= tol))
                for e in (np.arange(1, 5) * d // 5, np.arange(1, d, 8), np.arange(1, d)):
                    if i.size == 0:
                        break
                    keep = ~_span_fails(t, V, M, c, i, d, e, tol, uniform)
                    c, i = c[keep], i[keep]
                ok[c, i] = True
        valid[:, :w, d] = ok
    return valid if starts is None else valid[:, :starts]


def _valid_window_uniform(t: np.ndarray, V: np.ndarray, M: np.ndarray, tol: float, span: int,
                          starts: int | None = None) -> np.ndarray:
    """:func:`_valid_window` for uniform time steps (scene frames), shape (c, ``starts`` or f, span + 1).

    Every segment of span d has the same length h, so the Hermite basis at each interior offset is four numbers.
    The (curve, start) pairs still in play are kept as flat arrays and advance one span at a time; a pair leaves
    for good when no longer segment from its start can be valid (:func:`_no_longer_span`: the samples so far
    already rule out every cubic with the start's value and slope), so each start costs about the length of its
    longest valid segment instead of ``span``.  The tests per segment are the general path's, in the same order
    and the same arithmetic: exactly the segments whose max error is ≤ tol."""
    C, n = V.shape
    rows = n if starts is None else min(starts, n)
    valid = np.zeros((C, rows, span + 1), dtype=bool)
    s = min(rows, n - 1)                                              # starts with a segment
    if s <= 0 or span < 1:
        return valid
    step = float(t[1] - t[0])
    flat = (V.ravel(), M.ravel())
    Vf, Mf = flat
    d2 = np.zeros((C, n))
    d2[:, :n - 2] = np.abs(np.diff(V, 2, axis=1))
    d2f, out_flat = d2.ravel(), valid.reshape(-1)
    c_of, i_of = np.repeat(np.arange(C), s), np.tile(np.arange(s), C)
    st = _Starts(c_of * n + i_of, (c_of * rows + i_of) * (span + 1), n - 1 - i_of, Vf, Mf)
    slack = tol * (1.0 + 1e-6) + 1e-12 * (float(np.abs(V).max()) + float(np.abs(M).max()) * span * step)
    for d in range(1, span + 1):
        if d >= 3:
            st.live &= ~_no_longer_span(st, Vf, d - 1, step, slack)
        st.compact(d)
        if st.base.size == 0:
            break
        j = st.base + d
        vj, mj = Vf[j], Mf[j]
        np.maximum(st.top, vj, out=st.top)
        np.minimum(st.bottom, vj, out=st.bottom)
        if d == 1:                                                    # no sample between: always valid
            out_flat[st.out + 1] = True
            continue
        np.maximum(st.bend, d2f[j - 2], out=st.bend)
        ok = _uniform_tests(flat, st, vj, mj, d, d * step, step, tol)
        out_flat[st.out[ok & st.live] + d] = True
    return valid


class _Starts:
    """The (curve, start) pairs of :func:`_valid_window_uniform` still in play, as flat arrays: ``base`` (the
    start's index into ``V`` (c, f) flattened), ``out`` (into the result flattened), ``room`` (samples after
    the start), the start's value, slope and |slope|, the samples' range ``top``/``bottom`` and largest
    |Δ²V| ``bend`` in the current window, the slope interval ``lo``/``hi`` of :func:`_no_longer_span`, and
    ``live`` (False once no longer segment can be valid; such pairs are dropped in batches)."""

    __slots__ = ("base", "out", "room", "vi", "mi", "ami", "top", "bottom", "bend", "lo", "hi", "live")

    def __init__(self, base, out, room, Vf, Mf):
        self.base, self.out, self.room = base, out, room
        self.vi, self.mi = Vf[base], Mf[base]
        self.ami = np.abs(self.mi)
        self.top, self.bottom = self.vi.copy(), self.vi.copy()
        self.bend = np.zeros(base.size)
        self.lo, self.hi = np.full(base.size, -np.inf), np.full(base.size, np.inf)
        self.live = np.ones(base.size, dtype=bool)

    def compact(self, d: int) -> None:
        """Drop the pairs without room for span d, and the dead ones once they are a quarter of the rest."""
        short = self.room < d
        if not short.any() and 4 * np.count_nonzero(self.live) >= 3 * self.live.size:
            return
        keep = self.live & ~short
        for name in self.__slots__:
            setattr(self, name, getattr(self, name)[keep])


def _no_longer_span(st: _Starts, Vf: np.ndarray, last: int, step: float, slack: float) -> np.ndarray:
    """``True`` where no segment from the start can be valid once it spans sample ``last`` (any
    span > last).

    A valid segment's Hermite is ``v_i + m_i x + α x² + β x³`` (x the time from the start) with
    ``|P(x_k) − v_k| ≤ tol`` at every interior sample k, i.e. ``α + β x_k ∈ [(r_k − tol) / x_k², (r_k + tol) /
    x_k²]`` with ``r_k = v_k − v_i − m_i x_k``.  Two samples k < l bound β to
    ``[(r_l / x_l² − r_k / x_k²) ∓ tol (1 / x_l² + 1 / x_k²)] / (x_l − x_k)``; the pair (⌊l / 2⌋, l) is added for
    each new sample l = ``last`` and the intersection of the intervals kept (``st.lo``, ``st.hi``).  Once it is empty no
    α, β fit the samples so far, and every longer segment contains them.  ``slack`` (tol widened for rounding)
    keeps the test from dropping a segment the exact tests would accept."""
    if last < 2:
        return np.zeros(st.base.size, dtype=bool)
    k = last // 2
    xl, xk = last * step, k * step
    with np.errstate(over="ignore", invalid="ignore"):              # inf or NaN bounds drop nothing
        r_l = Vf[st.base + last] - st.vi - st.mi * xl
        r_k = Vf[st.base + k] - st.vi - st.mi * xk
        g = r_l * (1.0 / (xl * xl)) - r_k * (1.0 / (xk * xk))
        half = slack * (1.0 / (xl * xl) + 1.0 / (xk * xk))
        inv = 1.0 / (xl - xk)
        np.maximum(st.lo, (g - half) * inv, out=st.lo)
        np.minimum(st.hi, (g + half) * inv, out=st.hi)
        return st.lo > st.hi


def _uniform_tests(flat: tuple, st: _Starts, vj: np.ndarray, mj: np.ndarray, d: int, h: float, step: float,
                   tol: float) -> np.ndarray:
    """Which segments of span d ≥ 2 (length h) from the pairs ``st`` (ends ``vj``, ``mj``) are valid: the
    range bound, then every interior sample (d ≤ :data:`_WHOLE_SPAN`) or the middle one, then the survivors on
    4 samples, the grid (:func:`_grid_sure`) and their whole window (:func:`_window_fails`)."""
    Vf = flat[0]
    x = st.ami + np.abs(mj)
    x *= 4.0 / 27.0 * h
    b = st.top - st.bottom
    b += x
    ok = b <= tol
    e_max = None
    for e in range(1, d) if d <= _WHOLE_SPAN else (d // 2,):          # short spans whole, long: middle
        err = _hermite_abs(st, vj, mj, Vf[st.base + e], e / d, h)
        e_max = err if e_max is None else np.maximum(e_max, err, out=e_max)
    if d <= _WHOLE_SPAN:
        return ok | (e_max <= tol)
    q = np.flatnonzero(~ok & (e_max <= tol) & st.live)
    base = st.base[q]
    if q.size:
        keep = ~_window_fails(flat, d, h, base, np.arange(1, 5) * d // 5, tol)
        q, base = q[keep], base[keep]
    if q.size:
        fails, grid_err = _window_fails(flat, d, h, base, np.arange(_GRID, d, _GRID), tol, with_err=True)
        sure = _grid_sure(flat, st.bend[q], base, d, h, step, grid_err, tol) & ~fails
        ok[q[sure]] = True
        q, base = q[~fails & ~sure], base[~fails & ~sure]
    if q.size:
        ok[q[~_window_fails(flat, d, h, base, None, tol)]] = True
    return ok


def _hermite_abs(st: _Starts, vj: np.ndarray, mj: np.ndarray, ve: np.ndarray, s: float, h: float) -> np.ndarray:
    """``|Hermite − sample|`` at the fraction ``s`` of every segment from the pairs ``st`` (ends ``vj``, ``mj``,
    length h) to the samples ``ve`` there."""
    a0, a1, a2, a3 = (float(a) for a in _hermite_basis(np.float64(s)))
    out = st.vi * a0
    out += st.mi * (a1 * h)
    out += vj * a2
    out += mj * (a3 * h)
    out -= ve
    return np.abs(out, out=out)


#: Longest span :func:`_valid_window_uniform` evaluates at every interior sample for every start (longer spans:
#: at the middle sample, then the survivors on their whole window).
_WHOLE_SPAN = 12
#: Spacing (samples) of the grid on which :func:`_grid_check` evaluates a segment.
_GRID = 8


def _grid_sure(flat: tuple, bend: np.ndarray, base: np.ndarray, d: int, h: float, step: float,
               grid_err: np.ndarray, tol: float) -> np.ndarray:
    """Segments (span d, length h, starting at flat index ``base`` of ``V`` (c, f)) proven valid from their
    error on a grid of every :data:`_GRID`-th interior sample (``grid_err``, :func:`_window_fails`): the error
    E = P − V at the samples between two neighbouring known points a < b (grid samples or the ends, where
    E = 0) is within ``(k − a)(b − k) / 2 · max|Δ²E| ≤ g² / 8 · max|Δ²E|`` (g = b − a ≤ :data:`_GRID`) of the
    chord between E(a) and E(b), and ``|Δ²E| ≤ step² · max|P″| + max|Δ²V|``: the cubic's P″ is linear, so its
    largest size is at an end, ``|6 δ − 4 m_i − 2 m_j| / h`` or ``|6 δ − 2 m_i − 4 m_j| / h``
    (δ = (v_j − v_i) / h), and ``max|Δ²V|`` over each window is ``bend`` (len(base),).  Shape (len(base),)."""
    Vf, Mf = flat
    delta = 6.0 * (Vf[base + d] - Vf[base]) / h
    mi, mj = Mf[base], Mf[base + d]
    curv = np.maximum(np.abs(delta - 4.0 * mi - 2.0 * mj), np.abs(delta - 2.0 * mi - 4.0 * mj)) / h
    return grid_err + _GRID * _GRID / 8.0 * (step * step * curv + bend) <= tol


def _window_fails(flat: tuple, d: int, h: float, base: np.ndarray, e, tol: float, with_err: bool = False):
    """``True`` where the Hermite from sample ``base`` to base + d of ``V`` (c, f) flattened (``flat`` = (V, M)
    raveled; length h, uniform steps) is more than ``tol`` off at a sample base + e (``e`` interior offsets, or
    None: all of them), shape (len(base),).  The windows are rows of a strided view of the flattened ``V``
    (base + d stays in the curve's row), taken in blocks that bound the memory."""
    Vf, Mf = flat
    offs = np.arange(1, d) if e is None else np.asarray(e)
    H = np.column_stack(_hermite_basis(offs / d)) * np.array([1.0, h, 1.0, h])      # (E, 4)
    win = np.lib.stride_tricks.as_strided(Vf, shape=(Vf.size - d, d + 1), strides=(Vf.strides[0],) * 2,
                                          writeable=False) if e is None else None
    worst = np.zeros(base.size)
    step = max(1, _EVAL_BLOCK // (d + 1))
    for lo in range(0, base.size, step):
        bb = base[lo:lo + step]
        P = np.column_stack([Vf[bb], Mf[bb], Vf[bb + d], Mf[bb + d]])
        r = _products(P, H.T)
        if e is None:
            r -= win[bb][:, 1:d]
        else:
            r -= Vf[bb[:, None] + offs]
        worst[lo:lo + step] = np.abs(r).max(axis=1) if r.shape[1] else 0.0
    return (worst > tol, worst) if with_err else worst > tol


def _products(P: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """``P @ Q`` (P (r, 4)) with every row rounded as in a product of many rows: a one-row product goes to BLAS's
    matrix-vector kernel, whose rounding differs from the matrix-matrix one by an ulp, so a segment's verdict at
    tol would depend on which other segments share its block (and so on the CPU count)."""
    if P.shape[0] == 1:
        return (np.vstack([P, P]) @ Q)[:1]
    return P @ Q


def _held_spans(t: np.ndarray, v: np.ndarray, m: np.ndarray, tol: float, span: int) -> tuple:
    """Held poses longer than ``span`` samples, as extra stage-1 segments ``(starts (r,), ends (r,))`` sorted by
    start then end (:func:`_fewest_keys`).

    Exactly held: the runs i … j of samples of one value whose slopes (:func:`curve_slopes`) are all exactly zero,
    where the Hermite from i to j is that value (valid at any tolerance).  Nearly held (a solver's round-off, a
    slider resting a hair above zero, capture noise): the runs whose neighbouring samples differ by at most
    ``tol`` · :data:`_HELD_STEP`, as do the slopes over a step, each kept where the Hermite from its first sample
    to its last is within ``tol`` of every sample between (the stage-1 test), else halved until its pieces are
    (:func:`_within_tol`).  Stage 1 takes them as segments beyond its search, so a held pose costs two keys
    instead of one per ``span`` samples, which stage 2 would absorb one by one at a cost growing with the pose's
    length (the square of it: 93 samples per test instead of 16 on a 10-minute take solved per frame)."""
    dt = np.diff(t)
    exact = (m[:-1] == 0) & (m[1:] == 0) & (v[:-1] == v[1:])
    step = tol * _HELD_STEP
    near = exact | ((np.abs(np.diff(v)) <= step) & (np.abs(m[:-1]) * dt <= step) & (np.abs(m[1:]) * dt <= step))
    ei, ej = _runs(exact, span)
    pi, pj = _within_tol(t, v, m, tol, span, *_runs(near, span))
    # an exactly held run inside a kept nearly held one adds nothing
    host = np.searchsorted(pi, ei, side="right") - 1
    inside = (host >= 0) & (pj[np.maximum(host, 0)] >= ej) if pi.size else np.zeros(ei.size, dtype=bool)
    i, j = np.r_[ei[~inside], pi], np.r_[ej[~inside], pj]
    order = np.lexsort((j, i))
    return i[order], j[order]


#: A nearly held pose (:func:`_held_spans`): neighbouring samples within this fraction of the tolerance.
_HELD_STEP = 1e-2


def _runs(link: np.ndarray, span: int) -> tuple:
    """The maximal runs of samples i … j joined by ``link`` (f − 1,) (sample k to k + 1) longer than ``span``:
    ``(i (r,), j (r,))`` in order."""
    edge = np.diff(np.r_[False, link, False].astype(np.int8))
    i, j = np.flatnonzero(edge == 1), np.flatnonzero(edge == -1)
    long = j - i > span
    return i[long], j[long]


def _within_tol(t: np.ndarray, v: np.ndarray, m: np.ndarray, tol: float, span: int, i: np.ndarray,
                j: np.ndarray) -> tuple:
    """The segments i → j (disjoint, in order) whose Hermite (values and slopes of the curve at its ends) is within
    ``tol`` of every sample between, each one that is not halved until its pieces are or are no longer than
    ``span``: the pieces kept, ``(i, j)`` in order (pieces of one segment share their ends)."""
    keep_i, keep_j = [], []
    while i.size:
        bad = _segments_off(t, v, m, tol, i, j)
        keep_i.append(i[~bad])
        keep_j.append(j[~bad])
        mid = (i[bad] + j[bad]) // 2
        i, j = np.r_[i[bad], mid], np.r_[mid, j[bad]]
        long = j - i > span
        i, j = i[long], j[long]
    i, j = np.concatenate(keep_i or [i]), np.concatenate(keep_j or [j])
    order = np.argsort(i, kind="stable")
    return i[order], j[order]


def _segments_off(t: np.ndarray, v: np.ndarray, m: np.ndarray, tol: float, i: np.ndarray,
                  j: np.ndarray) -> np.ndarray:
    """``True`` per segment i → j (j − i ≥ 2) whose Hermite is more than ``tol`` off at a sample between."""
    inner = j - i - 1
    seg = np.repeat(np.arange(i.size), inner)
    k = i[seg] + 1 + np.arange(seg.size) - np.repeat(np.cumsum(inner) - inner, inner)
    h = t[j] - t[i]
    h00, h10, h01, h11 = _hermite_basis((t[k] - t[i][seg]) / h[seg])
    curve = h00 * v[i][seg] + h10 * (h * m[i])[seg] + h01 * v[j][seg] + h11 * (h * m[j])[seg]
    off = np.abs(curve - v[k]) > tol
    return np.logical_or.reduceat(off, np.cumsum(inner) - inner) if seg.size else np.zeros(i.size, dtype=bool)


def _fewest_keys(ok: np.ndarray, extra: tuple | None = None) -> list:
    """Shortest path from sample 0 to the last over the valid segments ``ok[i, d]`` (f, D + 1) and the
    ``extra`` ones (starts, ends: longer than D) (breadth-first: every segment costs one key); ties: the
    earliest previous key."""
    n, span = ok.shape[0], ok.shape[1] - 1
    f = np.flatnonzero(ok)                                            # sorted by start: CSR order
    counts = ok.sum(axis=1)
    cols = f - np.repeat(np.arange(n), counts) * span                 # i (D + 1) + d → i + d
    if extra is not None and extra[0].size:                           # longer than any span: each start's last
        ends = np.cumsum(counts)
        cols = np.insert(cols, ends[extra[0]], extra[1])
        counts = counts + np.bincount(extra[0], minlength=n)
    graph = csr_matrix((np.ones(cols.size), cols, np.r_[0, np.cumsum(counts)]), shape=(n, n))
    dist = _bfs_depth(breadth_first_order(graph, 0, directed=True, return_predecessors=True)[1])
    prev, start = np.full(n, -1), np.arange(n)                       # each sample's earliest previous key
    for d in range(1, span + 1):                                      # longer spans overwrite: earlier starts
        hit = ok[:n - d, d] & (dist[:n - d] == dist[d:] - 1)
        prev[d:][hit] = start[:n - d][hit]
    if extra is not None and extra[0].size:                           # longer than any span: earliest starts
        ei, ej = extra
        hit = dist[ei] == dist[ej] - 1
        first = np.full(n, n)
        np.minimum.at(first, ej[hit], ei[hit])
        prev[first < n] = first[first < n]
    prev = prev.tolist()
    keys = [n - 1]
    while keys[-1] > 0:
        keys.append(prev[keys[-1]])
    return keys[::-1]


def _bfs_depth(pred: np.ndarray) -> np.ndarray:
    """Depth of every node of a breadth-first tree rooted at node 0 from its predecessors ``pred`` (n,) (the
    root's negative): its distance from the root, by pointer doubling (log n vectorised steps)."""
    anc = np.where(pred < 0, 0, pred)
    depth = (anc != np.arange(anc.size)).astype(np.int64)
    live = np.flatnonzero(anc != 0)
    while live.size:                                                  # depth(v) += depth(anc(v)); anc(v) = anc²(v)
        up = anc[live]
        depth[live] += depth[up]
        anc[live] = anc[up]
        live = live[anc[live] != 0]
    return depth


def reduce_keys_bezier(times: ArrayLike, values: ArrayLike, tol: float, max_span: int = _MAX_SPAN,
                       refine: bool = True) -> tuple:
    """Fewest smooth Bézier keys (aligned handles) whose curve stays within ``tol`` (3.5.5).

    Two stages.  (1) Exact dynamic programming over subsets of the samples
    when each kept sample keeps its value and the dense curve's slope there
    (:func:`curve_slopes`): every segment is then a cubic Hermite fixed by its
    ends, segments are independent, and the fewest keys is a shortest path
    over the valid segments (searched up to ``max_span`` samples long).
    (2) ``refine``: sweep the keys and drop each one whose two neighbours can
    absorb it — their values and slopes refitted (least squares, else the
    minimax fit of :func:`chebyshev_fit`) so that the max error over the
    samples they govern stays within ``tol`` — until no key can go.  Stage 2 is what curve
    fitters like Blender's Decimate do; starting it from the optimal
    interpolating solution gives fewer keys at the same max error.  Many
    curves sampled at the same times are much faster together
    (:func:`reduce_keys_bezier_curves`, same result).

    Parameters
    ----------
    times : array_like, shape (f,)
        Strictly increasing sample times.
    values : array_like, shape (f,)
    tol : float
        Max absolute error allowed at every sample (≥ 0).
    max_span : int
        Longest segment searched in stage 1, in samples.
    refine : bool
        Run stage 2.

    Returns
    -------
    indices : ndarray of int (k,)
        Samples carrying a key (both ends always).
    key_values : ndarray (k,)
        Key values (stage 2 may move them off the samples by at most ``tol``-ish).
    slopes : ndarray (k,)
        Key slopes (value units per time unit); the handles lie along them at
        a third of each neighbouring segment (see :func:`hermite`).
    """
    t, v = _check_curve(times, values, tol)
    return reduce_keys_bezier_curves(t, v[:, None], tol, max_span, refine)[0]


def reduce_keys_bezier_curves(times: ArrayLike, values: ArrayLike, tol: float, max_span: int = _MAX_SPAN,
                              refine: bool = True, *, progress: ProgressFn | None = None) -> list:
    """:func:`reduce_keys_bezier` for many curves sampled at the same times, vectorised over the curves.

    Stage 1 tests each span for every curve and start still in play at once (in chunks of starts; a start
    leaves once the samples rule out any longer segment from it; blocks of curves on up to
    :data:`_MAX_WORKERS` threads, :func:`_stage_one`; a long take's curves are split into groups reduced in
    parallel, all but one in child processes, :func:`_reduce_groups`); stage 2
    runs the curves' sweeps in lock step, each sweep split into lanes of keys that hand over where they meet
    (:func:`_absorb_keys`: exactly the sequential sweep), one absorption test per lane and step solved for all
    lanes together (least squares by the normal equations, the minimax fits by a batched exchange algorithm,
    :func:`chebyshev_fit`'s); a test whose keys have not changed since it failed is not repeated.  Memory and
    time are linear in the number of samples (curves are processed in blocks of at most
    :data:`_BLOCK_SAMPLES` samples).

    Parameters
    ----------
    times : array_like, shape (f,)
        Strictly increasing sample times.
    values : array_like, shape (f, c)
        One curve per column.
    tol, max_span, refine
        As in :func:`reduce_keys_bezier`.
    progress : callable, optional
        ``progress(fraction)`` (:mod:`core.progress`) as the work goes on; raising
        :class:`~core.progress.Cancelled` from it stops the work.

    Returns
    -------
    list of c tuples (indices (k,), key_values (k,), slopes (k,))
        Per curve, as :func:`reduce_keys_bezier` returns.
    """
    t = array(times, "times", ndim=1)
    V = array(values, "values", ndim=2)
    if t.size != V.shape[0] or t.size < 1:
        raise ShapeSpaceError(f"times and values must be non-empty and of equal length, got {t.size} times and "
                              f"{V.shape[0]} rows of values", "shape")
    non_negative(tol, "tol")
    if isinstance(max_span, bool) or not isinstance(max_span, (int, np.integer)) or max_span < 1:
        raise ShapeSpaceError(f"max_span must be a whole number of samples ≥ 1, got {max_span!r}", "range")
    n = t.size
    if n > 1 and np.any(np.diff(t) <= 0):
        raise ShapeSpaceError("times must increase strictly", "order")
    V = np.ascontiguousarray(V.T)                                    # (c, f)
    M = np.vstack([curve_slopes(t, v) for v in V]) if V.size else np.zeros(V.shape)
    if n <= 2:
        return [(np.arange(n), V[k].copy(), M[k].copy()) for k in range(V.shape[0])]
    # an exactly constant curve (slopes all 0) is its two end keys: the segment from the first sample to the
    # last is that value, and stage 1 (a held pose, :func:`_held_spans`) and stage 2 (nothing between) agree
    out = [(np.array([0, n - 1]), V[k, [0, n - 1]], M[k, [0, n - 1]]) for k in range(V.shape[0])]
    moving = np.flatnonzero(np.any(V != V[:, :1], axis=1))
    if moving.size:
        groups = _process_groups(V[moving], tol)
        for rows, keys in zip(groups, _reduce_groups(t, V[moving], M[moving], tol, max_span, refine, groups,
                                                     progress)):
            for r, k in zip(rows.tolist(), keys):
                out[int(moving[r])] = k
    notify(progress, 1.0)
    return out


def _reduce_groups(t: np.ndarray, V: np.ndarray, M: np.ndarray, tol: float, max_span: int, refine: bool,
                   groups: list, progress: ProgressFn | None) -> list:
    """:func:`_reduce_group` on each group of rows of ``V`` (c, f) (moving curves): the first here, the others in
    child processes (:class:`~core.workers.ChildCall`) meanwhile; a group whose child gives no usable result is
    reduced here afterwards (the same function on the same rows: the same keys).  A cancel stops the children."""
    threads = min(_MAX_WORKERS, max(1, child_cpus() // len(groups)))
    children = []
    share = 1.0 / len(groups)
    try:
        for g in groups[1:]:
            children.append(ChildCall("keyreduce", "_reduce_group", (t, V[g], M[g], tol, max_span, refine, None,
                                                                     threads)))
        parts = [_reduce_group(t, V[groups[0]], M[groups[0]], tol, max_span, refine, scaled(progress, 0.0, share),
                               threads)]
        for k, (g, child) in enumerate(zip(groups[1:], children), start=1):
            got = child.result(progress, k * share)
            if not _usable(got, g.size, t.size):
                got = _reduce_group(t, V[g], M[g], tol, max_span, refine, scaled(progress, k * share,
                                                                                  (k + 1) * share))
            parts.append(got)
    finally:
        for child in children:
            child.stop()
    return parts


def _reduce_group(t: np.ndarray, V: np.ndarray, M: np.ndarray, tol: float, max_span: int, refine: bool,
                  progress: ProgressFn | None = None, threads: int | None = None) -> list:
    """Both stages for the curves ``V`` (c, f) (slopes ``M``; none constant): per curve (indices, values, slopes)
    as :func:`reduce_keys_bezier_curves` returns; stage 1 on ``threads`` threads (default :func:`_workers`)."""
    n = t.size
    idx = [[0, n - 1] for _ in range(V.shape[0])]
    first = 0.4 if refine else 1.0
    _stage_one(t, V, M, tol, max_span, idx, scaled(progress, 0.0, first), threads)
    kv = [V[k, i].tolist() for k, i in enumerate(idx)]
    km = [M[k, i].tolist() for k, i in enumerate(idx)]
    if refine:                                                        # stage 2: all curves in lock step
        _absorb_keys(t, V, idx, kv, km, tol, progress=scaled(progress, first, 1.0))
    return [(np.array(i), np.array(a), np.array(b)) for i, a, b in zip(idx, kv, km)]


def _usable(got, count: int, n: int) -> bool:
    """Whether a child's result has the shape of :func:`_reduce_group`'s for ``count`` curves of ``n`` samples."""
    if not isinstance(got, list) or len(got) != count:
        return False
    for keys in got:
        if not (isinstance(keys, tuple) and len(keys) == 3 and all(isinstance(a, np.ndarray) for a in keys)):
            return False
        i, a, b = keys
        if i.dtype.kind not in "iu" or a.dtype.kind != "f" or b.dtype.kind != "f":
            return False
        if not (i.ndim == 1 and i.size >= 2 and a.shape == b.shape == i.shape and i[0] == 0 and i[-1] == n - 1
                and np.all(np.diff(i) > 0) and np.isfinite(a).all() and np.isfinite(b).all()):
            return False
    return True


def _process_groups(V: np.ndarray, tol: float) -> list:
    """Rows of ``V`` (c, f) split into groups for :func:`_reduce_groups`: one group below
    :data:`_CHILD_SAMPLES` samples or on one CPU, else one per CPU (at most :data:`_MAX_PROCESSES`), balanced
    by each curve's ``Σ √(|Δ²v| / tol)``, largest first: the classic density of an optimal piecewise fit's knots,
    a proxy of its keys (which set the work; correlation 0.98–0.99 with the first stage's keys on the shipped
    take onto FBHead and ICT FaceKit, against 0.94–0.95 for the total variation)."""
    count = min(child_cpus(), _MAX_PROCESSES, V.shape[0]) if V.size >= _CHILD_SAMPLES else 1
    if count <= 1:
        return [np.arange(V.shape[0])]
    work = np.sqrt(np.abs(np.diff(V, 2, axis=1)) / max(tol, 1e-12)).sum(axis=1)
    load, size, members = np.zeros(count), np.zeros(count), [[] for _ in range(count)]
    for r in np.argsort(-work, kind="stable").tolist():
        g = int(np.lexsort((size, load))[0])                          # least work, then fewest curves
        members[g].append(r)
        load[g] += work[r]
        size[g] += 1
    return [np.array(sorted(m), dtype=np.intp) for m in members if m]


#: Samples (curves × frames) from which :func:`reduce_keys_bezier_curves` spreads the curves over child processes
#: (a child costs ~0.3 s to start; a 10-minute take has 1.8 M).
_CHILD_SAMPLES = 1 << 19
#: Most processes (this one and its children) key reduction uses.
_MAX_PROCESSES = 4


def _stage_one(t: np.ndarray, V: np.ndarray, M: np.ndarray, tol: float, max_span: int, idx: list,
               progress: ProgressFn | None, threads: int | None = None) -> None:
    """Stage 1 of :func:`reduce_keys_bezier_curves` into ``idx`` (the key indices of each curve, rows of ``V``
    (c, f)): the valid segments of the moving curves (:func:`_valid_segments`) and their fewest keys
    (:func:`_fewest_keys`), in blocks of curves of at most :data:`_BLOCK_SAMPLES` samples (memory) spread over
    :func:`_workers` threads (NumPy releases the GIL in its array passes; OpenBLAS is held to one thread meanwhile,
    :func:`~core.blas_threads.single_threaded`).  Progress is reported, and a cancel raised, from the calling
    thread; on a cancel the blocks not started are dropped and the running ones finish."""
    n = t.size
    moving = np.flatnonzero(np.any(V != V[:, :1], axis=1))
    if moving.size == 0:
        return
    span = min(max_span, n - 1)
    workers = threads or _workers()
    block = max(1, min(_BLOCK_SAMPLES // n, -(-moving.size // workers)))
    blocks = [moving[lo:lo + block] for lo in range(0, moving.size, block)]

    def run(rows: np.ndarray) -> list:
        ok = _valid_segments(t, V[rows], M[rows], tol, max_span)
        return [_fewest_keys(o, _held_spans(t, V[c], M[c], tol, span)) for c, o in zip(rows.tolist(), ok)]

    with single_threaded():                                           # held until every worker has stopped
        pool = ThreadPoolExecutor(max_workers=min(workers, len(blocks)), thread_name_prefix="shapespace-keyreduce")
        try:
            futures = [pool.submit(run, rows) for rows in blocks]
            done = 0
            for rows, fut in zip(blocks, futures):
                for c, keys in zip(rows.tolist(), fut.result()):
                    idx[c] = keys
                done += rows.size
                notify(progress, done / moving.size)
        finally:
            pool.shutdown(wait=True, cancel_futures=True)


def _workers() -> int:
    """Threads for stage 1: the CPUs this process may use, at most :data:`_MAX_WORKERS`."""
    return min(child_cpus(), _MAX_WORKERS)


#: Most threads stage 1 uses (beyond this the GIL held between NumPy's passes limits the gain).
_MAX_WORKERS = 4


def _ragged_argmax(vals: np.ndarray, starts: np.ndarray, owner: np.ndarray) -> tuple:
    """Per group of consecutive rows (group g starts at ``starts[g]``; ``owner`` the group of each row): the
    largest value and the first row holding it, each shape (len(starts),)."""
    top = np.maximum.reduceat(vals, starts)
    hit = np.flatnonzero(vals == top[owner])
    return top, hit[np.unique(owner[hit], return_index=True)[1]]


def _chebyshev_batch(A: np.ndarray, y: np.ndarray, owner: np.ndarray, starts: np.ndarray, first: np.ndarray,
                     stop_above: float, max_iter: int = 500) -> tuple:
    """:func:`chebyshev_fit` (k = 4 unknowns) for many systems at once, their rows stacked: system g is rows
    ``starts[g]`` … of ``A`` (R, 4), ``y`` (R,), ``owner`` (R,) the system of each row.  ``first`` (G, 5): a
    starting reference per system whose first four rows are independent.  Returns ``x`` (G, 4), ``err``
    (G,): the minimax error, or ``inf`` where the lower bound exceeded ``stop_above`` (or cycling), and
    ``bad`` (G,): the systems whose exchange met a singular reference (``err`` inf there; the caller takes
    another route).  Each system's arithmetic is its own (stacked LAPACK solves, one matrix each), so a system
    gets the same result in any batch, and a singular one leaves the batch without disturbing the others."""
    G = starts.size
    x = np.zeros((G, 4))
    err = np.full(G, np.inf)
    bad = np.zeros(G, dtype=bool)
    scale = np.maximum.reduceat(np.abs(y), starts)
    S = first.copy()
    u = np.ones((G, 5))
    sol, sing = _stacked_solve(np.transpose(A[S[:, :4]], (0, 2, 1)), A[S[:, 4]][..., None])
    u[:, :4] = -sol[..., 0]
    bad[sing] = True
    u *= np.where(np.einsum("gi,gi->g", u, y[S]) < 0, -1.0, 1.0)[:, None]      # start with h ≥ 0
    sigma = np.where(u < 0, -1.0, 1.0)
    w = np.abs(u) / np.abs(u).sum(axis=1, keepdims=True)
    act = np.flatnonzero(~sing)
    rows, grp, A_c, y_c = np.arange(y.size), owner, A, y                 # the rows of the running systems
    steps = 0
    while steps < max_iter:
        if act.size == 0:
            break
        if act.size != grp[-1] + 1:                                   # systems finished: drop their rows
            keep = np.zeros(G, dtype=bool)
            keep[act] = True
            m = keep[owner[rows]]
            rows, A_c, y_c = rows[m], A_c[m], y_c[m]
            grp = np.searchsorted(act, owner[rows])
        Sa, sa = S[act], sigma[act]
        Mm = np.concatenate([np.transpose(A[Sa] * sa[..., None], (0, 2, 1)), np.ones((act.size, 1, 5))], axis=1)
        pi, sing = _stacked_solve(np.transpose(Mm, (0, 2, 1)), (sa * y[Sa])[..., None])
        if sing.any():                                                # those leave; the same step for the others
            bad[act[sing]] = True
            act = act[~sing]
            continue
        steps += 1
        pi = pi[..., 0]
        xa, h = pi[:, :4], pi[:, 4]
        res = y_c - np.einsum("rk,rk->r", A_c, xa[grp])
        top, jl = _ragged_argmax(np.abs(res), np.searchsorted(grp, np.arange(act.size)), grp)
        j = rows[jl]
        over = h > stop_above
        conv = ~over & (top <= h + 1e-13 * scale[act])
        x[act[conv]], err[act[conv]] = xa[conv], top[conv]
        go = ~(over | conv)
        if not go.any():
            break
        tau = np.where(res[jl[go]] > 0, 1.0, -1.0)
        dd, sing = _stacked_solve(Mm[go], np.concatenate([tau[:, None] * A[j[go]], np.ones((tau.size, 1))],
                                                          axis=1)[..., None])
        g, jj, wa = act[go][~sing], j[go][~sing], w[act[go][~sing]]
        bad[act[go][sing]] = True
        tau, dd = tau[~sing], dd[~sing, :, 0]
        pos = dd > 1e-14
        ratios = np.where(pos, wa / np.where(pos, dd, 1.0), np.inf)
        leave = np.argmin(ratios, axis=1)
        r = ratios[np.arange(g.size), leave]
        wa = wa - r[:, None] * dd
        wa[np.arange(g.size), leave] = r
        w[g] = wa
        S[g, leave], sigma[g, leave] = jj, tau
        act = g
    return x, err, bad


def _stacked_solve(M: np.ndarray, b: np.ndarray) -> tuple:
    """``np.linalg.solve`` of the stacked systems ``M`` (G, k, k), ``b`` (G, k, 1) and which are singular (G,)
    (their solution 0): the others solved as in one call (each matrix its own LAPACK solve)."""
    try:
        return np.linalg.solve(M, b), np.zeros(M.shape[0], dtype=bool)
    except np.linalg.LinAlgError:                                     # rare: find the singular ones
        sing = np.zeros(M.shape[0], dtype=bool)
        out = np.zeros(b.shape)
        for g in range(M.shape[0]):
            try:
                out[g] = np.linalg.solve(M[g:g + 1], b[g:g + 1])[0]
            except np.linalg.LinAlgError:
                sing[g] = True
        return out, sing


def _absorb_batch(t: np.ndarray, V: np.ndarray, tests: list, idx: list, kv: list, km: list, tol: float,
                  curves: list | None = None, sigs: list | None = None) -> list:
    """Stage 2's absorption tests, one per entry of ``tests`` ``(curve, p, a, b)``: can keys p − 1 and p + 1
    of that curve (values and slopes refitted, keys a = max(p − 2, 0) and b = min(p + 2, last) held) absorb
    key p with max error ≤ tol?  Exactly the test of the scalar path (:func:`_absorb_system` rows, least
    squares then, if ‖r‖₂ / √m allows it, the minimax fit), solved for all tests together.  Returns the new
    (v, m, v, m) of keys p − 1, p + 1 per test, or None.  ``curves``: the row of ``V`` of each test when
    its first entry indexes the key lists but not ``V`` (default: the same); ``sigs``: per test, the indices of
    keys a, p − 1, p + 1, b then the values and slopes of a and b, when the caller has them."""
    B = len(tests)
    if sigs is None:
        K = np.array([[idx[c][a], idx[c][p - 1], idx[c][p + 1], idx[c][b]] for c, p, a, b in tests])
        held = np.array([[kv[c][a], km[c][a], kv[c][b], km[c][b]] for c, p, a, b in tests])
    else:
        both = np.array(sigs, dtype=np.float64).reshape(B, 8)
        K, held = both[:, :4].astype(np.int64), both[:, 4:]
    curve = np.array([c for c, _, _, _ in tests] if curves is None else curves)
    has = np.column_stack([K[:, 0] < K[:, 1], np.ones(B, dtype=bool), K[:, 3] > K[:, 2]])    # segments L, M, R
    seg_test, seg_kind = np.nonzero(has)                              # grouped by test, in order L, M, R
    s0, s1 = K[seg_test, seg_kind], K[seg_test, seg_kind + 1]
    length = s1 - s0 + 1
    row_seg = np.repeat(np.arange(seg_test.size), length)
    k = s0[row_seg] + np.arange(row_seg.size) - np.repeat(np.cumsum(length) - length, length)
    h = (t[s1] - t[s0])[row_seg]
    h00, h10, h01, h11 = _hermite_basis((t[k] - t[s0][row_seg]) / h)
    h10, h11 = h10 * h, h11 * h
    kind, owner = seg_kind[row_seg], seg_test[row_seg]
    left, mid, right = kind == 0, kind == 1, kind == 2
    A = np.zeros((k.size, 4))
    A[:, 0] = np.where(mid, h00, np.where(left, h01, 0.0))
    A[:, 1] = np.where(mid, h10, np.where(left, h11, 0.0))
    A[:, 2] = np.where(mid, h01, np.where(right, h00, 0.0))
    A[:, 3] = np.where(mid, h11, np.where(right, h10, 0.0))
    hv = held[owner]
    y = V[curve[owner], k] - np.where(left, h00 * hv[:, 0] + h10 * hv[:, 1],
                                      np.where(right, h01 * hv[:, 2] + h11 * hv[:, 3], 0.0))
    starts = np.searchsorted(owner, np.arange(B))
    rows = np.diff(np.r_[starts, owner.size])
    # least squares by the normal equations, columns scaled to unit norm; near-singular → scalar path
    Gm = np.add.reduceat(A[:, :, None] * A[:, None, :], starts)
    rhs = np.add.reduceat(A * y[:, None], starts)
    dg = np.sqrt(np.einsum("gii->gi", Gm))
    good = np.all(dg > 0, axis=1)
    D = 1.0 / np.where(dg > 0, dg, 1.0)
    Gs = Gm * D[:, :, None] * D[:, None, :]
    good &= np.linalg.eigvalsh(Gs)[:, 0] > 1e-10
    Gs[~good] = np.eye(4)
    x = np.linalg.solve(Gs, (rhs * D)[..., None])[..., 0] * D
    res = np.einsum("rk,rk->r", A, x[owner]) - y
    err = np.maximum.reduceat(np.abs(res), starts)
    norm = np.sqrt(np.add.reduceat(res * res, starts))
    out = [None] * B
    accept = good & (err <= tol * (1 - 1e-6)) & _slopes_safe(t, K, held, x, tol)
    xs = x.tolist()
    for g in np.flatnonzero(accept).tolist():
        out[g] = tuple(xs[g])
    # minimax where least squares misses but ‖r‖∞ ≥ ‖r_ls‖₂ / √m does not rule it out
    # the minimax fit starts from four samples of segment M (its ends and thirds: independent rows) and the
    # worst row of the least-squares fit; a segment M of three samples takes the scalar path
    mid_rows = K[:, 2] - K[:, 1] + 1
    # a segment M of three samples (keys p − 1, p, p + 1 adjacent) starts from its three rows and an interior
    # row of segment L (or R): independent, as only that row and M's middle one involve the slopes
    inner_l, inner_r = K[:, 1] - K[:, 0] >= 2, K[:, 3] - K[:, 2] >= 2
    startable = (mid_rows >= 4) | ((mid_rows == 3) & (inner_l | inner_r))
    cheb = good & (err > tol) & (norm <= tol * np.sqrt(rows)) & startable
    if cheb.any():
        g = np.flatnonzero(cheb)
        keep = cheb[owner]
        sub_owner = np.cumsum(cheb)[owner[keep]] - 1
        sub_starts = np.searchsorted(sub_owner, np.arange(g.size))
        base = np.flatnonzero(keep)                                   # row numbers in the sub-system
        remap = np.full(owner.size, -1)
        remap[base] = np.arange(base.size)
        m0 = starts[g] + np.where(has[g, 0], K[g, 1] - K[g, 0] + 1, 0)      # first row of segment M
        first = np.empty((g.size, 5), dtype=np.intp)
        pick = m0[:, None] + (np.arange(4) * (mid_rows[g, None] - 1)) // 3
        three = mid_rows[g] == 3
        pick[three, :3] = m0[three, None] + np.arange(3)
        pick[three, 3] = np.where(inner_l[g[three]], starts[g[three]] + 1, m0[three] + 4)
        first[:, :4] = remap[pick]
        score = np.abs(res[keep])
        score[first[:, :4].ravel()] = -1.0
        first[:, 4] = _ragged_argmax(score, sub_starts, sub_owner)[1]
        xc, ec, bad = _chebyshev_batch(A[keep], y[keep], sub_owner, sub_starts, first, tol)
        startable[g[bad]] = False                                     # a singular reference: the scalar path
        for q in np.flatnonzero((ec <= tol * (1 - 1e-6)) & _slopes_safe(t, K[g], held[g], xc, tol)).tolist():
            out[int(g[q])] = tuple(xc[q].tolist())
    # rank-deficient or tiny systems: the scalar path
    for gg in np.flatnonzero(~good | ((err > tol) & (norm <= tol * np.sqrt(rows)) & ~startable)):
        c, p, _, _ = tests[gg]
        out[gg] = _absorb_one(t, V[curve[gg]], idx[c], kv[c], km[c], p, tol)
    return out


def _absorb_one(t: np.ndarray, v: np.ndarray, idx: list, kv: list, km: list, p: int, tol: float):
    """The scalar absorption test (any rank): the new (v, m, v, m) of keys p − 1, p + 1, or None."""
    A, y = _absorb_system(t, v, idx, kv, km, p)
    x, err = _fit_two_keys(A, y)
    if err > tol and np.linalg.norm(A @ x - y) <= tol * np.sqrt(y.size):
        # ‖r‖∞ ≥ ‖r_ls‖₂ / √m for every fit, so only then can the minimax one be within tol
        x, err = chebyshev_fit(A, y, stop_above=tol)
    if x is None or err > tol * (1 - 1e-6):
        return None
    a, b = max(p - 2, 0), min(p + 2, len(idx) - 1)
    K = np.array([[idx[a], idx[p - 1], idx[p + 1], idx[b]]])
    if not _slopes_safe(t, K, np.array([[kv[a], km[a], kv[b], km[b]]]), np.asarray(x)[None], tol)[0]:
        return None
    return tuple(float(a) for a in x)


#: Largest ``|h · m|`` (a refitted key slope times the longest segment it shapes) an absorption may leave, in
#: tolerances or (:data:`_SLOPE_SIZE`) in the keys' values, whichever allows more: rounding in evaluating the
#: Hermite is a few ulps of it, 1e8 · tol · 2⁻⁵² · 16 ≈ 4e-7 · tol (inside the acceptance's 1e-6 · tol margin), or
#: 1e3 · 16 ulps of the values (at tolerances near the values' own precision).  Between keys with no sample between
#: them a least-squares slope is free, and refits across sweeps could grow it to 1e12 per time unit, whose
#: rounding alone then broke the tolerance (values of 1,500 at a tolerance of 0.0026).
_SLOPE_REACH = 1e8
#: See :data:`_SLOPE_REACH`.
_SLOPE_SIZE = 1e3


def _slopes_safe(t: np.ndarray, K: np.ndarray, held: np.ndarray, x: np.ndarray, tol: float) -> np.ndarray:
    """Per absorption test (keys a, p − 1, p + 1, b at samples ``K`` (B, 4); ``held`` (B, 4) value and slope of
    keys a and b; ``x`` (B, 4) the refitted values and slopes of keys p − 1 and p + 1): whether each refitted
    ``|h · m|`` (h the longest segment the slope shapes) is within :data:`_SLOPE_REACH` tolerances or
    :data:`_SLOPE_SIZE` times the largest key value involved (B,)."""
    h = np.diff(t[K], axis=1)                                         # segments L, M, R
    reach = np.column_stack([np.maximum(h[:, 0], h[:, 1]), np.maximum(h[:, 1], h[:, 2])])
    size = np.abs(np.column_stack([held[:, [0, 2]], x[:, [0, 2]]])).max(axis=1)
    bound = np.maximum(_SLOPE_REACH * tol, _SLOPE_SIZE * size)
    return np.all(np.abs(x[:, [1, 3]]) * reach <= bound[:, None], axis=1)


def _absorb_system(t: np.ndarray, v: np.ndarray, idx: list, kv: list, km: list, p: int) -> tuple:
    """Least-squares system ``A x ≈ y`` for the values and slopes x (4,) of keys p − 1 and p + 1 when key p
    goes: the samples of the up to three segments around it, the other keys held."""
    a, b = max(p - 2, 0), min(p + 2, len(idx) - 1)
    segs = ([(a, p - 1)] if a < p - 1 else []) + [(p - 1, p + 1)] + ([(p + 1, b)] if b > p + 1 else [])
    blocks, rhs = [], []
    for i0, i1 in segs:
        smp = np.arange(idx[i0], idx[i1] + 1)
        basis = _segment_basis(t[idx[i0]], t[idx[i1]], t[smp])
        A = np.zeros((smp.size, 4))
        y = v[smp].copy()
        for half, ki in ((0, i0), (1, i1)):
            cols = basis[:, 2 * half:2 * half + 2]
            if ki in (p - 1, p + 1):
                A[:, (0 if ki == p - 1 else 2):(2 if ki == p - 1 else 4)] += cols
            else:
                y -= cols @ np.array([kv[ki], km[ki]])
        blocks.append(A)
        rhs.append(y)
    return np.vstack(blocks), np.concatenate(rhs)


#: Keys per lane of :func:`_absorb_keys`: each curve's sweep is split into lanes of about this many keys.
_LANE_KEYS = 128
#: Most absorption tests solved together by :func:`_absorb_batch` (its temporaries stay in cache).
_BATCH_TESTS = 1024


class _Lane:
    """A piece of one curve's sweep in :func:`_absorb_keys`: the sweep as if it started at key ``start`` of the
    sweep's keys ``g`` (index, value and slope lists), on its own copy of them from ``base`` = max(start − 2, 0)
    on, copied as the cursor ``q`` advances (keys right of the cursor are untouched by the sweep so far).
    ``seen`` maps each cursor key (sample index) to the keys q − 2 … q (indices, values, slopes) then and q."""

    __slots__ = ("curve", "g", "start_key", "i", "v", "m", "q", "nxt", "seen", "top", "state", "after", "cut",
                 "into", "frm", "merge_key")

    def __init__(self, curve: int, g: tuple, start: int, after: int):
        base = max(start - 2, 0)
        self.curve, self.g, self.start_key = curve, g, g[0][start]
        self.i, self.v, self.m = g[0][base:start + 1], g[1][base:start + 1], g[2][base:start + 1]
        self.q, self.nxt = start - base, start + 1
        self.seen, self.top = {}, -1
        self.state = 0                       # 0 running, 1 reached the curve's end, 2 handed over, 3 not needed
        self.after = after                   # index of the next lane of the curve to compare with
        self.cut = self.into = self.frm = self.merge_key = None


def _lane_compare(lanes: list, lane: _Lane, c: int):
    """The later lane's record at cursor key ``c`` that ``lane`` continues into when its keys q − 2 … q equal
    it: (lane, record), None when no later lane covers ``c``, or ``False`` to wait for a lane not there yet."""
    while lane.after < len(lanes):
        k = lanes[lane.after]
        if k.state == 2 and c >= k.merge_key:                         # from there on, k is a later lane
            lane.after += 1
            continue
        if k.start_key > c:
            return None
        rec = k.seen.get(c)
        if rec is not None:
            return k, rec
        return False if k.state == 0 and k.top < c else None
    return None


def _lanes_done(lanes: list):
    """The sweep's keys (index, value, slope lists) when the lanes from the first one on reach the curve's end
    through their hand-overs, else None."""
    lane, pos, parts = lanes[0], 0, []
    while lane.state == 2:
        parts.append((lane, pos, lane.cut))
        lane, pos = lane.into, lane.frm
    if lane.state != 1:
        return None
    parts.append((lane, pos, len(lane.i)))
    return tuple([x for ln, a, b in parts for x in getattr(ln, f)[a:b]] for f in ("i", "v", "m"))


def _start_lanes(curve: int, g: tuple) -> list:
    """The lanes of one sweep over keys ``g`` (lane k starts at key 1 + k · :data:`_LANE_KEYS`)."""
    starts = range(1, len(g[0]) - 1, _LANE_KEYS)
    return [_Lane(curve, g, s, k + 1) for k, s in enumerate(starts)]


def _lane_advance(lanes: list, lane: _Lane, failed: dict):
    """Move ``lane`` to its next absorption test: ``(q, a, b, sig)``, or None when it reached the curve's end,
    handed over to a later lane (its keys q − 2 … q equal that lane's at the same cursor key: from there on
    the sweep is that lane's) or waits for one.  Tests known to fail (``failed``) are skipped."""
    gi, gv, gm = lane.g
    n = len(gi)
    i, v, m = lane.i, lane.v, lane.m
    while True:
        q = lane.q
        size = len(i)
        if size < q + 3 and lane.nxt < n:                            # copy the sweep's keys up to q + 2
            lo, hi = lane.nxt, min(lane.nxt + q + 3 - size, n)
            i += gi[lo:hi]
            v += gv[lo:hi]
            m += gm[lo:hi]
            lane.nxt, size = hi, size + hi - lo
        if q >= size - 1:
            lane.state = 1
            return None
        c = i[q]
        a = max(q - 2, 0)
        win = (*i[a:q + 1], *v[a:q + 1], *m[a:q + 1])
        lane.seen[c] = (win, q)
        lane.top = c
        look = _lane_compare(lanes, lane, c)
        if look is False:
            return None
        if look is not None and look[1][0] == win:
            lane.state, lane.cut, lane.into, lane.frm, lane.merge_key = 2, a, look[0], look[1][1] - 2, c
            return None
        b = min(q + 2, len(i) - 1)
        sig = (i[a], i[q - 1], i[q + 1], i[b], v[a], m[a], v[b], m[b])
        if failed.get(c) != sig:
            return q, a, b, sig
        lane.q += 1


def _absorb_keys(t: np.ndarray, V: np.ndarray, idx: list, kv: list, km: list, tol: float,
                 max_sweeps: int = 4, progress: ProgressFn | None = None) -> None:
    """Stage 2 of :func:`reduce_keys_bezier`, in place on the key lists of every curve (rows of ``V``): each
    curve sweeps its keys left to right, dropping every key its neighbours can absorb, until a sweep drops
    none (at most ``max_sweeps``).  A test is skipped when the keys it reads are exactly those of its last
    failure (it would fail again).

    Each sweep is split into lanes (:class:`_Lane`) of :data:`_LANE_KEYS` keys, all lanes of all curves
    advancing in lock step with their current tests solved together (:func:`_absorb_batch`).  A lane is the
    sweep as if it started at its first key.  The sweep's future from a cursor depends only on the keys from
    q − 2 on, and everything right of q is still the sweep's input, so when a lane reaches a cursor key that
    the next lane has passed with the same keys q − 2 … q (indices, values and slopes), the two sweeps are
    the same from there on and the lane hands over; otherwise it goes on (waiting for the next lane if it is
    ahead of it).  The lanes chained from the first one are exactly the sequential sweep: the same keys, each
    test the same pure function of the keys it reads, in a number of steps set by the lane length instead of
    the take's."""
    C = len(idx)
    sweep = [0] * C
    failed = [{} for _ in range(C)]
    lanes = [_start_lanes(c, (list(idx[c]), list(kv[c]), list(km[c]))) or None for c in range(C)]
    running = [ln for c in range(C) if lanes[c] for ln in lanes[c]]
    step = 0
    while running:
        step += 1
        if progress is not None and step % 32 == 0:                  # the first sweep dominates the work
            notify(progress, _absorb_done(lanes, sweep))
        tests, sigs, owners, still, touched = _next_tests(running, lanes, failed)
        if tests:
            _run_tests(t, V, tol, tests, sigs, owners, failed)
        for c in touched:
            still += _end_sweep(c, lanes, sweep, (idx, kv, km), max_sweeps)
        running = [ln for ln in still if ln.state == 0]


def _absorb_done(lanes: list, sweep: list) -> float:
    """The fraction of :func:`_absorb_keys`' work done (each curve's first sweep counts 0.9 of it)."""
    C = len(lanes)
    return sum(1.0 if lanes[c] is None else 0.9 * (sweep[c] > 0 or sum(
        ln.state != 0 for ln in lanes[c]) / len(lanes[c])) for c in range(C)) / C


def _next_tests(running: list, lanes: list, failed: list) -> tuple:
    """Advance every running lane to its next test: ``(tests, sigs, owners, still running, curves touched)``."""
    tests, sigs, owners, still, touched = [], [], [], [], set()
    for lane in running:
        if lane.state != 0:
            continue
        nxt = _lane_advance(lanes[lane.curve], lane, failed[lane.curve])
        if nxt is not None:
            q, a, b, sig = nxt
            tests.append((len(owners), q, a, b))
            owners.append(lane)
            sigs.append(sig)
        if lane.state == 0:
            still.append(lane)
        else:
            touched.add(lane.curve)
    return tests, sigs, owners, still, touched


def _run_tests(t, V, tol: float, tests: list, sigs: list, owners: list, failed: list) -> None:
    """Solve the lanes' current tests in cache-sized batches and apply them: a key absorbed is dropped (its
    neighbours take the fitted values and slopes), a failure is remembered by the keys it read."""
    res = []
    for lo in range(0, len(tests), _BATCH_TESTS):
        part = owners[lo:lo + _BATCH_TESTS]
        res += _absorb_batch(t, V, [(k, q, a, b) for k, (_, q, a, b) in enumerate(tests[lo:lo + _BATCH_TESTS])],
                             [ln.i for ln in part], [ln.v for ln in part], [ln.m for ln in part], tol,
                             [ln.curve for ln in part], sigs[lo:lo + _BATCH_TESTS])
    for (_, q, _, _), sig, lane, x in zip(tests, sigs, owners, res):
        if x is None:
            failed[lane.curve][lane.i[q]] = sig
            lane.q += 1
        else:
            lane.v[q - 1], lane.m[q - 1], lane.v[q + 1], lane.m[q + 1] = x
            del lane.i[q], lane.v[q], lane.m[q]


def _end_sweep(c: int, lanes: list, sweep: list, keys: tuple, max_sweeps: int) -> list:
    """When curve ``c``'s lanes have chained through the whole sweep, take its keys and start the next sweep
    (while it still drops keys, at most ``max_sweeps``); the new lanes to run (none otherwise)."""
    if lanes[c] is None:
        return []
    out = _lanes_done(lanes[c])
    if out is None:
        return []
    for ln in lanes[c]:                                       # lanes off the chain: not needed
        if ln.state == 0:
            ln.state = 3
    changed = len(out[0]) < len(lanes[c][0].g[0])
    idx, kv, km = keys
    idx[c][:], kv[c][:], km[c][:] = out
    sweep[c] += 1
    lanes[c] = (_start_lanes(c, out) if changed and sweep[c] < max_sweeps else []) or None
    return lanes[c] or []
