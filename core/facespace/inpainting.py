"""Covariance inpainting and superresolution of animation curves (thesis 9.3).

J.P. Lewis, *Learning from the Artist*, 2016, section 9.3: fill the unknown samples of
a curve with the Gaussian conditional mean ``x_u = m_u + C_uk C_kk⁻¹ (x_k − m_k)`` given
the known samples around each gap, the covariance (time × channel) learned from the
curve itself — so known channels also predict a missing one (superresolution: a knee
from the hips).  :func:`linear_fill` and :func:`cubic_fill` are the references it is
judged against.
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import ArrayLike
from scipy.interpolate import CubicSpline
from scipy.linalg import cho_solve

from .. import validate
from ..errors import ErrorCode
from ..result import Issue, Result, ShapeSpaceError, Status
from ._common import count

__all__ = ["inpaint_curve", "context_channels", "linear_fill", "cubic_fill", "gap_mask", "fill_gap"]


def _curve(values, known):
    """Values (T, c), known mask (T, c) and whether ``values`` was 1-D, checked."""
    X = validate.array(values, "values", finite=False)
    one_d = X.ndim == 1
    X = X[:, None] if one_d else X
    if X.ndim != 2 or X.shape[0] < 2 or X.shape[1] < 1:
        raise ShapeSpaceError(f"values must have shape (T,) or (T, c) with T ≥ 2, got {np.shape(values)}",
                              ErrorCode.SHAPE)
    T, c = X.shape
    M = np.asarray(known)
    if M.dtype != bool:
        raise ShapeSpaceError(f"known must be a boolean mask, got dtype {M.dtype}", ErrorCode.DTYPE)
    if M.shape == (T,):
        M = np.repeat(M[:, None], c, axis=1)
    elif M.shape != X.shape or one_d:
        alt = "" if one_d else f" or {X.shape} like values"
        raise ShapeSpaceError(f"known must have shape ({T},){alt}, got {M.shape}", ErrorCode.SHAPE)
    if not M.any():
        raise ShapeSpaceError("known marks no sample as known: nothing to inpaint from", ErrorCode.NO_KNOWN)
    empty = np.flatnonzero(~M.any(axis=0))
    if empty.size:
        raise ShapeSpaceError(f"values channel(s) {empty.tolist()} have no known samples", ErrorCode.NO_KNOWN)
    if not np.isfinite(X[M]).all():
        raise ShapeSpaceError("values contain NaN or infinite entries at known samples", ErrorCode.NON_FINITE)
    return X, M, one_d


def _fill(values, known, curve):
    X, M, one_d = _curve(values, known)
    t = np.arange(X.shape[0], dtype=np.float64)
    out = np.column_stack([curve(t[M[:, j]], X[M[:, j], j], t) for j in range(X.shape[1])])
    out[M] = X[M]
    return out[:, 0] if one_d else out


def linear_fill(values: ArrayLike, known: ArrayLike) -> np.ndarray:
    """Reference fill: per-channel linear interpolation of the known samples, ends held constant.

    Parameters
    ----------
    values : array_like, shape (T,) or (T, c)
    known : array_like of bool, shape (T,) or like ``values``

    Returns
    -------
    ndarray, shape of ``values``
    """
    return _fill(values, known, lambda tk, xk, t: np.interp(t, tk, xk))


def cubic_fill(values: ArrayLike, known: ArrayLike) -> np.ndarray:
    """Reference fill: per-channel scipy ``CubicSpline`` through the known samples, ends held constant.

    Parameters
    ----------
    values : array_like, shape (T,) or (T, c)
    known : array_like of bool, shape (T,) or like ``values``

    Returns
    -------
    ndarray, shape of ``values``
    """
    return _fill(values, known, lambda tk, xk, t: CubicSpline(tk, xk)(np.clip(t, tk[0], tk[-1])) if tk.size > 1
                 else np.full(t.size, xk[0]))


def _block_toeplitz(gamma):
    """Window covariance (L·c, L·c), time-major, from γ[τ, a, b] = Cov(x_a(t), x_b(t + τ)), τ < L."""
    L, c, _ = gamma.shape
    lag = np.arange(L)[None, :] - np.arange(L)[:, None]                      # j − i
    G = np.where((lag >= 0)[:, :, None, None], gamma[np.abs(lag)], gamma[np.abs(lag)].transpose(0, 1, 3, 2))
    C = G.transpose(0, 2, 1, 3).reshape(L * c, L * c)
    return (C + C.T) / 2.0


def _window_model(X, M, mu, L, gamma_given):
    """Mean (L·c,), covariance (L·c, L·c) of a length-L window, the method name and a fallback note."""
    T, c = X.shape
    D = L * c
    if gamma_given is not None:
        return np.tile(mu, L), _block_toeplitz(gamma_given[:L]), "given_autocovariance", None
    full = M.all(axis=1)
    ok = np.convolve(full.astype(int), np.ones(L, dtype=int), "valid") == L if T >= L else np.zeros(0, bool)
    need = max(2 * D, D + 10)
    if ok.sum() >= need:
        Z = sliding_window_view(X, L, axis=0)[ok].transpose(0, 2, 1).reshape(-1, D)
        return Z.mean(axis=0), np.atleast_2d(np.cov(Z, rowvar=False)), "window_covariance", None
    # Pairwise-available lag products normalised per lag (the obvious alternative) give an indefinite
    # matrix and clearly worse fills than the biased estimator on a provisionally filled curve.
    Y = cubic_fill(X, M) - mu
    gamma = np.zeros((L, c, c))
    for tau in range(min(L, T)):
        gamma[tau] = Y[:T - tau].T @ Y[tau:] / T
    return np.tile(mu, L), _block_toeplitz(gamma), "autocovariance", f"{int(ok.sum())}/{need} for length {L}"


def _gamma_argument(autocovariance, c, active, L):
    g = autocovariance(np.arange(L)) if callable(autocovariance) else autocovariance
    g = np.asarray(g, dtype=np.float64)
    g = g.reshape(-1, 1, 1) if (g.ndim == 1 and c == 1) else g
    if g.ndim != 3 or g.shape[0] < L or g.shape[1:] != (c, c) or not np.isfinite(g).all():
        alt = f" or (≥{L},)" if c == 1 else ""
        raise ShapeSpaceError(f"autocovariance must have shape (≥{L}, {c}, {c}){alt} with finite values, "
                              f"got {g.shape}", ErrorCode.SHAPE)
    return g[:, active][:, :, active]


def _conditional_mean(m, C, k, u, x_k, ridge):
    """``m_u + C_uk (C_kk + ρ·mean(diag C) I)⁻¹ (x_k − m_k)`` (the prior mean when nothing is known)."""
    if not k.size:
        return m[u]
    Ckk = C[np.ix_(k, k)] + ridge * max(float(np.mean(np.diag(C))), 1e-300) * np.eye(k.size)
    rhs = x_k - m[k]
    try:    # numpy's Cholesky: scipy's potrf is far slower on small matrices with threaded BLAS
        sol = cho_solve((np.linalg.cholesky(Ckk), True), rhs, check_finite=False)
    except np.linalg.LinAlgError:
        sol = np.linalg.lstsq(Ckk, rhs, rcond=None)[0]
    return m[u] + C[np.ix_(u, k)] @ sol


def _gaps(Ma):
    """(start, stop) of every run of frames where some active channel is unknown."""
    rows = ~Ma.all(axis=1)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], rows.astype(int), [0]])))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2])]


def _summary(gaps, diag, models, constant, issues, n_unknown):
    """Message, status and sorted issues of :func:`inpaint_curve`."""
    notes = [model[3] for model in models.values() if model[3]]
    if notes:
        issues.insert(0, Issue("warning", "autocovariance_fallback", "too few fully-known windows ("
                               + ", ".join(notes) + "): used a regularised autocovariance estimate instead"))
    if constant:
        issues.append(Issue("info", "constant_channel", f"channel(s) {constant} are constant: filled with the "
                            "constant", tuple(f"channel {j}" for j in constant)))
    used = sorted(set(diag["methods"]))
    diag["method"] = "+".join(used) if used else ("constant" if constant else "none")
    message = (f"filled {n_unknown} unknown sample(s) in {len(gaps)} gap(s) by the Gaussian conditional mean "
               f"({diag['method']})" if gaps else f"filled {n_unknown} unknown sample(s)")
    message = "; ".join([message] + [i.message for i in issues])
    issues.sort(key=lambda i: i.severity != "warning")
    status = Status.WARNING if any(i.severity == "warning" for i in issues) else Status.OK
    return message, status


def inpaint_curve(values: ArrayLike, known: ArrayLike, window: int | None = None, ridge: float = 1e-6,
                  autocovariance: ArrayLike | Callable | None = None) -> Result:
    """Fill unknown samples of a curve with the Gaussian conditional mean (thesis 9.3).

    Each gap (a run of frames where some channel is unknown) is filled with
    ``x_u = m_u + C_uk (C_kk + ρ I)⁻¹ (x_k − m_k)`` over a window of L = gap + 2 × context
    frames centred on it; k are the known samples in the window (every known channel,
    including known channels inside the gap — the superresolution case), u the gap's
    unknown ones.  The window covariance C (L·c × L·c, time-major × channel) is by
    preference the empirical covariance of all fully-known length-L windows of the curve;
    with fewer than max(2 L c, L c + 10) of them a stationary autocovariance is used
    instead, regularised: the biased (positive semi-definite) estimator on the curve with
    its gaps provisionally filled by :func:`cubic_fill`.  Known samples are returned
    exactly.  A gap at a curve end is conditioned on one side only and drifts toward the
    mean; a constant channel is filled with its constant.

    Parameters
    ----------
    values : array_like, shape (T,) or (T, c)
        Curve samples; unknown entries may hold anything (NaN included).
    known : array_like of bool, shape (T,) or (T, c)
        True where the sample is known ((T,) marks whole frames).
    window : int, optional
        Context frames used on each side of a gap; default max(gap length, 8).
    ridge : float
        ρ relative to the mean window variance, added to C_kk for stability.
    autocovariance : array_like (≥ L, c, c) or (≥ L,), or callable(lags) -> that, optional
        Known stationary autocovariance γ[τ, a, b] = Cov(x_a(t), x_b(t + τ)) to use instead of
        estimating one; the mean is then the known-sample mean.

    Returns
    -------
    Result
        ``value``: the filled curve, shape of ``values``; status WARNING with an end gap or the
        autocovariance fallback.  ``diagnostics``: ``gaps`` [(start, stop)], ``window_lengths``,
        ``contexts``, ``methods`` (per gap), ``method``, ``constant_channels``.
    """
    X, M, one_d = _curve(values, known)
    T, c = X.shape
    if window is not None:
        window = count(window, "window", 1, "whole number of frames")
    ridge = validate.non_negative(ridge, "ridge")
    mu = np.array([X[M[:, j], j].mean() for j in range(c)])
    constant = [j for j in range(c) if np.ptp(X[M[:, j], j]) <= 1e-12 * max(1.0, abs(mu[j]))]
    active = [j for j in range(c) if j not in constant]
    out = np.where(M, X, np.nan)
    for j in constant:
        out[~M[:, j], j] = X[M[:, j], j][0]
    Xa, Ma, ca = np.where(M, X, 0.0)[:, active], M[:, active], len(active)
    gaps = _gaps(Ma)
    issues, models, diag = [], {}, {"gaps": gaps, "window_lengths": [], "contexts": [], "methods": [],
                                     "constant_channels": constant}
    for start, stop in gaps:
        ctx = window if window is not None else max(stop - start, 8)
        L = stop - start + 2 * ctx
        if L not in models:
            gamma = None if autocovariance is None else _gamma_argument(autocovariance, c, active, L)
            models[L] = _window_model(Xa, Ma, mu[active], L, gamma)
        m, C, method, _ = models[L]
        lo = start - ctx
        frames = np.arange(max(lo, 0), min(stop + ctx, T))
        idx = ((frames - lo)[:, None] * ca + np.arange(ca)).ravel()
        obs = Ma[frames].ravel()
        in_gap = ((frames >= start) & (frames < stop))[:, None].repeat(ca, axis=1).ravel()
        x_u = _conditional_mean(m, C, idx[obs], idx[~obs & in_gap], Xa[frames].ravel()[obs], ridge)
        block = out[frames][:, active]
        block[~Ma[frames] & in_gap.reshape(-1, ca)] = x_u
        out[np.ix_(frames, active)] = block
        for key, v in (("window_lengths", L), ("contexts", ctx), ("methods", method)):
            diag[key].append(v)
        if start == 0 or stop == T:
            issues.append(Issue("warning", "end_gap", f"gap at frames {start}–{stop - 1} touches the curve end: "
                                "conditioned on one side only (drifts toward the mean)", (f"frames {start}-{stop}",)))
    message, status = _summary(gaps, diag, models, constant, issues, int((~M).sum()))
    return Result(out[:, 0] if one_d else out, status=status, message=message, diagnostics=diag, issues=issues)


def context_channels(values: ArrayLike, target: int, known: ArrayLike, gap_length: int,
                     window: int | None = None) -> np.ndarray:
    """Which other channels should inform the fill of ``target``'s gap (superresolution, 9.3).

    The window covariance of :func:`inpaint_curve` needs at least 2 L c fully-known windows of length
    L = gap + 2 × context to be estimated empirically; with all channels of a rig or a skeleton it
    never has them and falls back to an autocovariance that adds little.  So the channels are ranked
    by how strongly their frame-to-frame changes correlate with the target's on frames where the target
    is known, and only as many are kept as the data can support.

    Parameters
    ----------
    values : array_like, shape (T, c)
    target : int
        Column of the channel with the gap.
    known : array_like of bool, shape (T,)
        Frames where the target is known.
    gap_length : int
    window : int, optional
        Context frames per side (default as :func:`inpaint_curve`: max(gap, 8)).

    Returns
    -------
    ndarray of int, shape (k,)
        Column indices, ``target`` first, then the chosen channels by decreasing correlation.
    """
    X = validate.array(values, "values", finite=False)
    if X.ndim != 2 or not 0 <= int(target) < X.shape[1]:
        raise ShapeSpaceError(f"values must have shape (T, c) and target a column of it, got {X.shape}, {target}",
                              ErrorCode.SHAPE)
    M = np.asarray(known, dtype=bool)
    if M.shape != (X.shape[0],):
        raise ShapeSpaceError(f"known must have shape ({X.shape[0]},), got {M.shape}", ErrorCode.SHAPE)
    ctx = int(window) if window is not None else max(int(gap_length), 8)
    L = int(gap_length) + 2 * ctx
    budget = int((X.shape[0] - L + 1) // (2 * L)) - 1          # channels the windows can support
    if budget < 1 or X.shape[1] < 2:
        return np.array([target])
    both = M[1:] & M[:-1]
    D = np.diff(X, axis=0)[both]
    D = D - D.mean(axis=0)
    norms = np.linalg.norm(D, axis=0)
    score = np.zeros(X.shape[1])
    ok = norms > 1e-12 * max(float(norms.max(initial=0.0)), 1e-300)
    if ok[target]:
        score[ok] = np.abs(D[:, ok].T @ D[:, target]) / (norms[ok] * norms[target])
    score[target] = -1.0
    order = [int(j) for j in np.argsort(-score) if score[j] > 0.2][:budget]
    return np.array([int(target)] + order)


def gap_mask(frames: ArrayLike, start: float, end: float) -> np.ndarray:
    """Which of ``frames`` lie in the gap ``start … end`` (inclusive), checked against the frames.

    Parameters
    ----------
    frames : array_like, shape (T,)
        The animation's (sorted) sample frames.
    start, end : float
        First and last frame of the gap.

    Returns
    -------
    ndarray of bool, shape (T,)
    """
    frames = validate.array(frames, "frames", ndim=1)
    if end < start:
        raise ShapeSpaceError(f"the gap ends ({end}) before it starts ({start})", ErrorCode.RANGE)
    if not frames.size or not (frames[0] <= start <= end <= frames[-1]):
        span = f"{frames[0]:g}–{frames[-1]:g}" if frames.size else "(none)"
        raise ShapeSpaceError(f"the gap {start}–{end} is outside the animation's frames {span}", ErrorCode.RANGE)
    return (frames >= start) & (frames <= end)


def fill_gap(values: ArrayLike, gap: ArrayLike) -> Result:
    """Fill channel 0 of ``values`` over the frames ``gap``, helped by the channels that correlate (9.3).

    :func:`context_channels` picks which of the other columns (all known through the gap)
    the data can support; :func:`inpaint_curve` fills channel 0 from them.

    Parameters
    ----------
    values : array_like, shape (T, c)
        Column 0 is the curve with the gap; the others are candidate context curves.
    gap : array_like of bool, shape (T,)
        Frames of the gap in column 0.

    Returns
    -------
    Result
        ``value``: column 0 filled, shape (T,) (exact outside the gap).  Status, message and
        issues of :func:`inpaint_curve`; ``diagnostics`` its own plus ``channels``, the columns
        used (0 first).
    """
    X = validate.array(values, "values", ndim=2, finite=False)
    gap = np.asarray(gap, dtype=bool)
    chosen = context_channels(X, 0, ~gap, int(gap.sum()))
    known = np.ones((X.shape[0], chosen.size), bool)
    known[gap, 0] = False
    res = inpaint_curve(X[:, chosen], known)
    return Result(np.asarray(res.value)[:, 0], status=res.status, message=res.message,
                  diagnostics=dict(res.diagnostics, channels=chosen), issues=res.issues)
