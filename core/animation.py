"""F-Curve maths: sampling keyframed curves, frame-rate conversion and key reduction (thesis 3.5.5).

Blender's F-Curves are piecewise: each key's ``interpolation`` governs the
segment that starts at it.  :func:`sample_keys` evaluates the ``CONSTANT`` and
``LINEAR`` cases exactly and vectorised; the bridge falls back to Blender's
own ``FCurve.evaluate`` for Bézier and easing segments or curve modifiers.
:func:`frames_to_seconds` / :func:`seconds_to_frames` convert between scene
frames and capture time.

Key reduction turns a dense curve (one sample per frame) into the fewest keys
whose curve stays within a max-error tolerance of every sample:

- :func:`reduce_keys` — linear keys, a subset of the samples (exact dynamic
  programming over valid segments);
- :func:`reduce_keys_bezier` — smooth Bézier keys with aligned handles: exact
  dynamic programming over sample subsets keeping the dense curve's slope
  (:func:`curve_slopes`), then a refinement that refits neighbours to absorb
  keys; :func:`hermite` is the cubic Hermite Blender evaluates for such keys.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .result import ShapeSpaceError
from .validate import array, non_negative

__all__ = ["CONSTANT", "LINEAR", "sample_keys", "frames_to_seconds", "seconds_to_frames",
           "reduce_keys", "reduce_keys_bezier", "curve_slopes", "hermite", "chebyshev_fit"]

CONSTANT = 0
LINEAR = 1


def sample_keys(key_frames: ArrayLike, key_values: ArrayLike, interpolation: ArrayLike, frames: ArrayLike,
                extrapolate_linear: bool = False) -> np.ndarray:
    """Evaluate one curve of CONSTANT/LINEAR keys at ``frames``.

    Parameters
    ----------
    key_frames : array_like, shape (m,)
        Strictly increasing key times (frames, may be fractional).
    key_values : array_like, shape (m,)
    interpolation : array_like of int, shape (m,)
        :data:`CONSTANT` or :data:`LINEAR` per key (governs the segment after it).
    frames : array_like, shape (f,)
        Where to sample.
    extrapolate_linear : bool
        Blender's "Linear Extrapolation": continue the first/last segment's
        slope instead of holding the end values.

    Returns
    -------
    ndarray, shape (f,)
    """
    x = np.asarray(key_frames, dtype=np.float64)
    y = np.asarray(key_values, dtype=np.float64)
    mode = np.asarray(interpolation, dtype=np.int64)
    t = np.asarray(frames, dtype=np.float64)
    if x.ndim != 1 or x.shape != y.shape or x.shape != mode.shape:
        raise ShapeSpaceError(
            f"key_frames, key_values and interpolation must be 1-D of equal length; got "
            f"{x.shape}, {y.shape}, {mode.shape}", "shape")
    if x.size == 0:
        raise ShapeSpaceError("a curve needs at least one key", "empty_curve")
    if x.size > 1 and np.any(np.diff(x) <= 0):
        raise ShapeSpaceError("key_frames must be strictly increasing", "unsorted")
    if x.size == 1:
        return np.full(t.shape, y[0])
    seg = np.clip(np.searchsorted(x, t, side="right") - 1, 0, x.size - 2)
    x0, x1, y0, y1 = x[seg], x[seg + 1], y[seg], y[seg + 1]
    frac = (t - x0) / (x1 - x0)
    lin = y0 + (y1 - y0) * frac
    out = np.where(mode[seg] == LINEAR, lin, np.where(t >= x1, y1, y0))
    before, after = t < x[0], t > x[-1]
    if extrapolate_linear:
        s0 = (y[1] - y[0]) / (x[1] - x[0]) if mode[0] == LINEAR else 0.0
        # Blender: each end extrapolates by its own key's interpolation (a CONSTANT end key holds)
        s1 = (y[-1] - y[-2]) / (x[-1] - x[-2]) if mode[-1] == LINEAR else 0.0
        out = np.where(before, y[0] + s0 * (t - x[0]), out)
        out = np.where(after, y[-1] + s1 * (t - x[-1]), out)
    else:
        out = np.where(before, y[0], out)
        out = np.where(after, y[-1], out)
    return out


def frames_to_seconds(frames: ArrayLike, fps: float, fps_base: float = 1.0,
                      frame_offset: float = 0.0) -> np.ndarray:
    """Scene frames → seconds (Blender: ``fps / fps_base`` frames per second)."""
    if fps <= 0 or fps_base <= 0:
        raise ShapeSpaceError(f"fps must be positive, got {fps}/{fps_base}", "fps")
    return (np.asarray(frames, dtype=np.float64) - frame_offset) * fps_base / fps


def seconds_to_frames(seconds: ArrayLike, fps: float, fps_base: float = 1.0,
                      frame_offset: float = 0.0) -> np.ndarray:
    """Seconds → scene frames (inverse of :func:`frames_to_seconds`)."""
    if fps <= 0 or fps_base <= 0:
        raise ShapeSpaceError(f"fps must be positive, got {fps}/{fps_base}", "fps")
    return np.asarray(seconds, dtype=np.float64) * fps / fps_base + frame_offset


# ------------------------------------------------------------------ key reduction (thesis 3.5.5)
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
        Exchange steps before giving up (degenerate cycling; ``x`` None, error inf).

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
    S, sigma, w = _chebyshev_start(Ar, y)
    scale = float(np.abs(y).max())
    last = np.ones(k + 1)
    for _ in range(max_iter):
        Minv = np.linalg.inv(np.vstack([(Ar[S] * sigma[:, None]).T, last]))
        pi = Minv.T @ (sigma * y[S])
        xr, h = pi[:k], pi[k]
        if h > stop_above:
            return None, float(h)
        res = y - Ar @ xr
        j = int(np.argmax(np.abs(res)))
        if abs(res[j]) <= h + 1e-13 * scale:
            x[cols] = xr
            return x, float(np.abs(res).max())
        tau = 1.0 if res[j] > 0 else -1.0
        dd = Minv @ np.r_[tau * Ar[j], 1.0]
        pos = dd > 1e-14
        ratios = np.where(pos, w / np.where(pos, dd, 1.0), np.inf)
        leave = int(np.argmin(ratios))
        w = w - ratios[leave] * dd
        w[leave] = ratios[leave]
        S[leave], sigma[leave] = j, tau
    return None, np.inf


def _valid_segments(t: np.ndarray, v: np.ndarray, m: np.ndarray, tol: float, max_span: int) -> np.ndarray:
    """``ok[i, d]``: the Hermite from sample i to i + d (sample values and slopes) stays within ``tol`` of
    every sample between, shape (f, max_span + 1).  Vectorised over i for each span d; a span is accepted at
    once when a bound proves it, long spans are first tested on 4 then every 8th interior sample (failing
    there is failing), and only the survivors on all."""
    n = t.size
    ok = np.zeros((n, max_span + 1), dtype=bool)
    top, bottom = v.copy(), v.copy()                                 # range of the samples in [i, i + d]
    for d in range(1, min(max_span, n - 1) + 1):
        np.maximum(top[:n - d], v[d:], out=top[:n - d])
        np.minimum(bottom[:n - d], v[d:], out=bottom[:n - d])
        i = np.arange(n - d)
        # accepted without evaluation: h00 + h01 = 1 (both ≥ 0) and |h10|, |h11| ≤ 4/27 on [0, 1], so the
        # curve stays within the samples' range widened by 4/27 · h · (|m_i| + |m_j|)
        bound = top[i] - bottom[i] + 4.0 / 27.0 * (t[i + d] - t[i]) * (np.abs(m[i]) + np.abs(m[i + d]))
        sure = bound <= tol
        ok[i[sure], d] = True
        i = i[~sure]
        if d > 1:
            subsets = (np.arange(1, d, 1),) if d <= 12 else (np.arange(1, 5) * d // 5, np.arange(1, d, 8),
                                                              np.arange(1, d, 1))
            for e in subsets:
                if i.size == 0:
                    break
                i = i[_span_errors(t, v, m, i, d, e) <= tol]
        ok[i, d] = True
    return ok


def _span_errors(t: np.ndarray, v: np.ndarray, m: np.ndarray, i: np.ndarray, d: int, e: np.ndarray) -> np.ndarray:
    """Max error at samples i + e of the Hermite segments from i to i + d, shape (len(i),)."""
    j, k = i + d, i[:, None] + e[None, :]
    h = (t[j] - t[i])[:, None]
    s = (t[k] - t[i][:, None]) / h
    h00, h10 = (1 + 2 * s) * (1 - s) ** 2, s * (1 - s) ** 2
    h01, h11 = s * s * (3 - 2 * s), s * s * (s - 1)
    curve = h00 * v[i][:, None] + h10 * h * m[i][:, None] + h01 * v[j][:, None] + h11 * h * m[j][:, None]
    return np.abs(curve - v[k]).max(axis=1)


def _interpolating_keys(t: np.ndarray, v: np.ndarray, m: np.ndarray, tol: float, max_span: int) -> list:
    """Stage 1 of :func:`reduce_keys_bezier`: the fewest samples whose Hermite (sample values and slopes)
    stays within ``tol``, by a shortest path over the valid segments up to ``max_span`` samples long (ties:
    the earliest previous key)."""
    n = t.size
    ok = _valid_segments(t, v, m, tol, max_span)
    spans = np.arange(ok.shape[1])
    big = np.iinfo(np.int64).max
    best = np.full(n, big)
    prev = np.full(n, -1)
    best[0] = 1
    for j in range(1, n):
        d = spans[: min(j, max_span) + 1]
        starts = j - d[ok[j - d, d]]                                  # valid segments ending at j
        if starts.size:
            b = best[starts]
            low = b.min()
            if low < big:
                best[j] = low + 1
                prev[j] = starts[b == low].min()
    return _shortest_path(prev)


def reduce_keys_bezier(times: ArrayLike, values: ArrayLike, tol: float, max_span: int = 128,
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
    interpolating solution gives fewer keys at the same max error.

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
    n = t.size
    if n > 1 and np.any(np.diff(t) <= 0):
        raise ShapeSpaceError("times must increase strictly", "order")
    m = curve_slopes(t, v)
    if n <= 2:
        return np.arange(n), v.copy(), m
    idx = _interpolating_keys(t, v, m, tol, max_span)
    kv, km = list(v[idx]), list(m[idx])
    if refine:
        _absorb_keys(t, v, idx, kv, km, tol)
    return np.array(idx), np.array(kv), np.array(km)


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


def _absorb_keys(t: np.ndarray, v: np.ndarray, idx: list, kv: list, km: list, tol: float,
                 max_sweeps: int = 4) -> None:
    """Stage 2 of :func:`reduce_keys_bezier`, in place on the key lists."""
    for _ in range(max_sweeps):
        changed, p = False, 1
        while p < len(idx) - 1:
            A, y = _absorb_system(t, v, idx, kv, km, p)
            x, err = _fit_two_keys(A, y)
            if err > tol and np.linalg.norm(A @ x - y) <= tol * np.sqrt(y.size):
                # ‖r‖∞ ≥ ‖r_ls‖₂ / √m for every fit, so only then can the minimax one be within tol
                x, err = chebyshev_fit(A, y, stop_above=tol)
            if err <= tol * (1 - 1e-6):
                kv[p - 1], km[p - 1], kv[p + 1], km[p + 1] = x
                del idx[p], kv[p], km[p]
                changed = True
            else:
                p += 1
        if not changed:
            return
