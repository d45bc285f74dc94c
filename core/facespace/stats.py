"""Face-space statistics, motion inpainting and pose-space confidence (thesis ch. 6 and 9).

- **Face-space Gaussian** (3.7.9, ch. 6), a "probability meter": in n dimensions the whitened norm of a
  typical face is χ-distributed, so the mass sits in a thin shell of radius ≈ √n and the mean face itself
  is *atypical* — frames are flagged both when too extreme and when too average.
- **Shell interpolation** (6.5): slerp the whitened direction, lerp the radius, instead of cutting
  through the improbable interior as a plain lerp does.
- **Covariance inpainting / superresolution** (9.3): fill unknown curve samples with the Gaussian
  conditional mean given the known samples around each gap, the covariance (time × channel) learned
  from the curve itself, so known channels also predict a missing one.
- **Pose-space confidence** (9.1–9.2): Gaussian-process posterior variance of pose-space interpolation
  and a per-vertex predictive standard deviation showing where a new sculpted example would matter.

Reference: J.P. Lewis, *Learning from the Artist*, 2016.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy import stats
from scipy.interpolate import CubicSpline
from scipy.linalg import cho_solve, solve_triangular

from .. import rbf
from ..result import Issue, Result, ShapeSpaceError

__all__ = [
    "FaceGaussian", "fit_face_gaussian", "shell_interpolate", "linear_interpolate", "inpaint_curve", "context_channels",
    "linear_fill", "cubic_fill",
]



def _trailing(a, name, n, what="channels"):
    a = np.asarray(a, dtype=np.float64)
    if a.ndim < 1 or a.shape[-1] != n:
        raise ShapeSpaceError(f"{name} must have shape (..., {n}) ({n} {what}), got {a.shape}", "shape")
    if not np.isfinite(a).all():
        raise ShapeSpaceError(f"{name} contains NaN or infinite values", "non_finite")
    return a


# ------------------------------------------------------------------ face-space Gaussian (3.7.9, ch. 6)
@dataclass
class FaceGaussian:
    """A Gaussian over face-space weight vectors (thesis 3.7.9, ch. 6).

    Attributes
    ----------
    mean : ndarray, shape (n,)
    eigvecs : ndarray, shape (n, n)
        Covariance eigenvectors (columns), by decreasing variance.
    eigvals : ndarray, shape (n,)
        Whitening variances: covariance eigenvalues λ_i plus ``ridge``.
    dimension : float
        Effective dimension d = Σ λ_i / (λ_i + ridge) = E‖z‖² under the fitted covariance: n without
        a ridge, about the covariance rank with one.
    ridge : float
    regularised : bool
    message : str
    diagnostics : dict
        ``constant_channels``, ``frames``, ``condition`` (before the ridge).
    """

    mean: np.ndarray
    eigvecs: np.ndarray
    eigvals: np.ndarray
    dimension: float
    ridge: float = 0.0
    regularised: bool = False
    message: str = "ok"
    diagnostics: dict = field(default_factory=dict)

    def whiten(self, w) -> np.ndarray:
        """z = Λ^{-1/2} Vᵀ (w − μ) for weights ``w`` (..., n), shape (..., n)."""
        w = _trailing(w, "w", self.mean.size)
        return ((w - self.mean) @ self.eigvecs) / np.sqrt(self.eigvals)

    def unwhiten(self, z) -> np.ndarray:
        """Inverse of :meth:`whiten`: w = μ + V Λ^{1/2} z, shape (..., n)."""
        z = _trailing(z, "z", self.mean.size)
        return self.mean + (z * np.sqrt(self.eigvals)) @ self.eigvecs.T

    def face_norm(self, w) -> np.ndarray:
        """Mahalanobis distance ‖z‖ of ``w`` (..., n) from the mean face, shape (...)."""
        return np.linalg.norm(self.whiten(w), axis=-1)

    @property
    def shell_radius(self) -> float:
        """Mode of the χ distribution with d degrees of freedom, √(d − 1) (0 when d ≤ 1)."""
        return float(np.sqrt(max(self.dimension - 1.0, 0.0)))

    def percentile(self, w) -> np.ndarray:
        """χ² CDF of ‖z‖² with d degrees of freedom, shape (...): 0 at the mean face, → 1 far out."""
        return stats.chi2.cdf(self.face_norm(w) ** 2, self.dimension)

    def plausibility(self, w, alpha: float = 0.01) -> Result:
        """Per-frame plausibility of faces ``w`` (..., n) (ch. 6: the mean face is atypical).

        ``value`` is an array (...) of ``"too_extreme"`` (percentile > 1 − α/2),
        ``"too_average"`` (percentile < α/2) or ``"typical"``; diagnostics hold
        ``norm`` and ``percentile`` (...), ``shell_radius``, ``dimension``, ``alpha``.
        """
        if not (np.isfinite(alpha) and 0 < alpha < 1):
            raise ShapeSpaceError(f"alpha must lie strictly between 0 and 1, got {alpha}", "range")
        norm = self.face_norm(w)
        pct = stats.chi2.cdf(norm ** 2, self.dimension)
        status = np.where(pct > 1 - alpha / 2, "too_extreme", np.where(pct < alpha / 2, "too_average", "typical"))
        issues = [Issue("info", "regularised", self.message)] if self.regularised else []
        flat = status.reshape(-1)
        for code, text in (("too_extreme", "farther from the mean face than real faces get"),
                           ("too_average", "closer to the mean face than real faces get (the mean is atypical)")):
            idx = np.flatnonzero(flat == code)
            if idx.size:
                issues.append(Issue("warning", code, f"{idx.size} frame(s) are {text}",
                                    tuple(f"frame {i}" for i in idx)))
        bad = int(np.count_nonzero(flat != "typical"))
        message = f"{bad} of {flat.size} frame(s) implausible at α = {alpha:g}"
        return Result(value=status, status=1 if bad else 0, message=message, diagnostics={"norm": norm, "percentile": pct, "alpha": float(alpha),
                      "dimension": self.dimension, "shell_radius": self.shell_radius}, issues=issues)

    def implausible_frames(self, frames_weights, alpha: float = 0.01):
        """Indices (k,) of the frames of ``frames_weights`` (f, n) that are not typical, and per index its
        reason, ``"too_extreme"`` or ``"too_average"`` (see :meth:`plausibility`)."""
        W = _trailing(frames_weights, "frames_weights", self.mean.size)
        if W.ndim != 2:
            raise ShapeSpaceError(f"frames_weights must have shape (frames, {self.mean.size}), got {W.shape}",
                                  "shape")
        status = self.plausibility(W, alpha).value
        idx = np.flatnonzero(status != "typical")
        return idx, [str(s) for s in status[idx]]


def fit_face_gaussian(weights, ridge: float = None) -> FaceGaussian:
    """Fit the face-space Gaussian to animation frames (thesis 3.7.9, ch. 6).

    Parameters
    ----------
    weights : array_like, shape (f, n)
        Blendshape weights, one row per frame.
    ridge : float, optional
        Variance added to every covariance eigenvalue.  By default none, unless f ≤ n, a channel is
        constant or the covariance is singular; then 1e-3 × the mean channel variance (1e-6 when every
        channel is constant), said in ``message``.  Constant channels are whitened with the ridge.
    """
    W = np.asarray(weights, dtype=np.float64)
    if W.ndim != 2:
        raise ShapeSpaceError(f"weights must have shape (frames, channels), got {W.shape}", "shape")
    f, n = W.shape
    if f < 2 or n < 1:
        raise ShapeSpaceError(f"weights needs at least 2 frames and 1 channel, got shape {W.shape}", "too_few")
    if not np.isfinite(W).all():
        raise ShapeSpaceError("weights contains NaN or infinite values", "non_finite")
    if ridge is not None and not (np.isfinite(ridge) and ridge > 0):
        raise ShapeSpaceError(f"ridge must be positive and finite, got {ridge}", "range")
    mean = W.mean(axis=0)
    C = np.atleast_2d(np.cov(W, rowvar=False))
    lam, V = np.linalg.eigh(C)
    lam, V = np.clip(lam[::-1], 0.0, None), V[:, ::-1]
    constant = np.flatnonzero(np.ptp(W, axis=0) <= 1e-12 * max(1.0, float(np.abs(W).max())))
    reasons = [text for cond, text in ((f <= n, f"only {f} frames for {n} channels"),
                                       (constant.size, f"{constant.size} constant channel(s) {constant.tolist()}"),
                                       (lam[-1] <= 1e-10 * lam[0], "the covariance is singular")) if cond]
    scale = float(np.mean(np.diag(C)))
    message = f"face Gaussian of {n} channels from {f} frames"
    how = "given"
    if ridge is None and reasons:
        ridge = 1e-3 * scale if scale > 0 else 1e-6
        how = "1e-3 × mean variance" if scale > 0 else "1e-6: every channel is constant"
    ridge = float(ridge or 0.0)
    dim = float(n) if ridge == 0 else max(float(np.sum(lam / (lam + ridge))), 1e-12)
    if ridge:
        why = " because " + ", ".join(reasons) if reasons else ""
        message += f"; regularised with ridge {ridge:.3g} ({how}){why}; effective dimension {dim:.3g}"
    cond = float(lam[0] / lam[-1]) if lam[-1] > 0 else np.inf
    return FaceGaussian(mean, V, lam + ridge, dim, ridge, ridge > 0, message,
                        {"constant_channels": constant.tolist(), "frames": f, "condition": cond})


# ------------------------------------------------------------------ shell interpolation (6.5)
def _check_t(t):
    t = np.atleast_1d(np.asarray(t, dtype=np.float64))
    if t.ndim != 1 or not np.isfinite(t).all() or t.min(initial=0) < 0 or t.max(initial=0) > 1:
        raise ShapeSpaceError(f"t must be a 1-D array of values in [0, 1], got shape {t.shape}", "range")
    return t


def _endpoints(w0, w1, n):
    out = []
    for name, w in (("w0", w0), ("w1", w1)):
        w = np.asarray(w, dtype=np.float64)
        if w.shape != (n,):
            raise ShapeSpaceError(f"{name} must have shape ({n},), got {w.shape}", "shape")
        out.append(_trailing(w, name, n))
    return out


def linear_interpolate(w0, w1, t) -> np.ndarray:
    """Plain lerp (1 − t) w0 + t w1 for faces ``w0``, ``w1`` (n,) at ``t`` (k,), shape (k, n)."""
    w0, w1 = _endpoints(w0, w1, np.size(w0))
    t = _check_t(t)[:, None]
    return (1.0 - t) * w0 + t * w1


def shell_interpolate(g: FaceGaussian, w0, w1, t) -> np.ndarray:
    """Interpolate between faces along the probability shell (thesis 6.5).

    In whitened coordinates the direction is slerped from z0/‖z0‖ to z1/‖z1‖ and the radius goes
    linearly from ‖z0‖ to ‖z1‖, so the Mahalanobis norm is kept when the endpoints share it (a lerp dips
    toward the atypical mean).  Special cases: an endpoint at the mean face (‖z‖ ≈ 0) has no direction,
    so the path is the radial line, identical to the lerp; antipodal endpoints have no unique great
    circle, so the path turns through the whitened axis most perpendicular to z0 (in 1-D, where the
    shell is two points, it falls back to the lerp).  Endpoints are reproduced exactly.

    Parameters
    ----------
    g : FaceGaussian
    w0, w1 : array_like, shape (n,)
    t : array_like, shape (k,), values in [0, 1]

    Returns
    -------
    ndarray, shape (k, n)
    """
    if not isinstance(g, FaceGaussian):
        raise ShapeSpaceError("g must be a FaceGaussian (see fit_face_gaussian)", "type")
    n = g.mean.size
    w0, w1 = _endpoints(w0, w1, n)
    t = _check_t(t)
    z0, z1 = g.whiten(w0), g.whiten(w1)
    r0, r1 = float(np.linalg.norm(z0)), float(np.linalg.norm(z1))
    tc = t[:, None]
    z = (1.0 - tc) * z0 + tc * z1                      # the lerp: radial line / 1-D antipodes
    if min(r0, r1) > 1e-12 * max(r0, r1):
        u0, u1 = z0 / r0, z1 / r1
        omega = float(np.arccos(np.clip(u0 @ u1, -1.0, 1.0)))
        u = None
        if omega < 1e-6:                               # (nearly) the same direction
            u = (1.0 - tc) * u0 + tc * u1
        elif np.pi - omega >= 1e-6:
            u = (np.sin((1.0 - tc) * omega) * u0 + np.sin(tc * omega) * u1) / np.sin(omega)
        elif n > 1:                                    # antipodal: turn through a fixed perpendicular axis
            p = np.eye(n)[int(np.argmin(np.abs(u0)))]
            p = p - (p @ u0) * u0
            u = np.cos(omega * tc) * u0 + np.sin(omega * tc) * p / np.linalg.norm(p)
        if u is not None:
            z = ((1.0 - tc) * r0 + tc * r1) * u / np.linalg.norm(u, axis=1, keepdims=True)
    out = g.unwhiten(z)
    out[t == 0] = w0
    out[t == 1] = w1
    return out


# ------------------------------------------------------------------ inpainting / superresolution (9.3)
def _curve(values, known):
    X = np.asarray(values, dtype=np.float64)
    one_d = X.ndim == 1
    X = X[:, None] if one_d else X
    if X.ndim != 2 or X.shape[0] < 2 or X.shape[1] < 1:
        raise ShapeSpaceError(f"values must have shape (T,) or (T, c) with T ≥ 2, got {np.shape(values)}", "shape")
    T, c = X.shape
    M = np.asarray(known)
    if M.dtype != bool:
        raise ShapeSpaceError(f"known must be a boolean mask, got dtype {M.dtype}", "dtype")
    if M.shape == (T,):
        M = np.repeat(M[:, None], c, axis=1)
    elif M.shape != X.shape or one_d:
        alt = "" if one_d else f" or {X.shape} like values"
        raise ShapeSpaceError(f"known must have shape ({T},){alt}, got {M.shape}", "shape")
    if not M.any():
        raise ShapeSpaceError("known marks no sample as known: nothing to inpaint from", "no_known")
    empty = np.flatnonzero(~M.any(axis=0))
    if empty.size:
        raise ShapeSpaceError(f"values channel(s) {empty.tolist()} have no known samples", "no_known")
    if not np.isfinite(X[M]).all():
        raise ShapeSpaceError("values contain NaN or infinite entries at known samples", "non_finite")
    return X, M, one_d


def _fill(values, known, curve):
    X, M, one_d = _curve(values, known)
    t = np.arange(X.shape[0], dtype=np.float64)
    out = np.column_stack([curve(t[M[:, j]], X[M[:, j], j], t) for j in range(X.shape[1])])
    out[M] = X[M]
    return out[:, 0] if one_d else out


def linear_fill(values, known) -> np.ndarray:
    """Reference fill: per-channel linear interpolation of the known samples, ends held constant.

    ``values`` (T,) or (T, c), ``known`` (T,) or like ``values``; returns the shape of ``values``.
    """
    return _fill(values, known, lambda tk, xk, t: np.interp(t, tk, xk))


def cubic_fill(values, known) -> np.ndarray:
    """Reference fill: per-channel scipy ``CubicSpline`` through the known samples, ends held constant."""
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
                              f"got {g.shape}", "shape")
    return g[:, active][:, :, active]


def inpaint_curve(values, known, window: int = None, ridge: float = 1e-6, autocovariance=None) -> Result:
    """Fill unknown samples of a curve with the Gaussian conditional mean (thesis 9.3).

    Each gap (a run of frames where some channel is unknown) is filled with x_u = m_u + C_uk (C_kk + ρ I)⁻¹
    (x_k − m_k) over a window of L = gap + 2 × context frames centred on it; k are the known samples in
    the window (every known channel, including known channels inside the gap — the superresolution
    case), u the gap's unknown ones.  The window covariance C (L·c × L·c, time-major × channel) is by
    preference the empirical covariance of all fully-known length-L windows of the curve; with fewer
    than max(2 L c, L c + 10) of them a stationary autocovariance is used instead, regularised: the
    biased (positive semi-definite) estimator on the curve with its gaps provisionally filled by
    :func:`cubic_fill`.  Known samples are returned exactly.  A gap at a curve end is conditioned on one
    side only and drifts toward the mean; a constant channel is filled with its constant.

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
        ``value``: the filled curve, shape of ``values``.  ``diagnostics``: ``gaps`` [(start, stop)],
        ``window_lengths``, ``contexts``, ``methods`` (per gap), ``method``, ``constant_channels``.
    """
    X, M, one_d = _curve(values, known)
    T, c = X.shape
    if window is not None and not (int(window) == window and window >= 1):
        raise ShapeSpaceError(f"window must be a positive whole number of frames, got {window}", "range")
    if not (np.isfinite(ridge) and ridge >= 0):
        raise ShapeSpaceError(f"ridge must be non-negative and finite, got {ridge}", "range")
    mu = np.array([X[M[:, j], j].mean() for j in range(c)])
    constant = [j for j in range(c) if np.ptp(X[M[:, j], j]) <= 1e-12 * max(1.0, abs(mu[j]))]
    active = [j for j in range(c) if j not in constant]
    out = np.where(M, X, np.nan)
    for j in constant:
        out[~M[:, j], j] = X[M[:, j], j][0]
    Xa, Ma, ca = np.where(M, X, 0.0)[:, active], M[:, active], len(active)
    rows = ~Ma.all(axis=1)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], rows.astype(int), [0]])))
    gaps = [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2])]
    issues, models, diag = [], {}, {"gaps": gaps, "window_lengths": [], "contexts": [], "methods": [],
                                     "constant_channels": constant}
    for start, stop in gaps:
        ctx = int(window) if window is not None else max(stop - start, 8)
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
        k, u = idx[obs], idx[~obs & in_gap]
        if k.size:
            Ckk = C[np.ix_(k, k)] + ridge * max(float(np.mean(np.diag(C))), 1e-300) * np.eye(k.size)
            rhs = Xa[frames].ravel()[obs] - m[k]
            try:    # numpy's Cholesky: scipy's potrf is far slower on small matrices with threaded BLAS
                sol = cho_solve((np.linalg.cholesky(Ckk), True), rhs, check_finite=False)
            except np.linalg.LinAlgError:
                sol = np.linalg.lstsq(Ckk, rhs, rcond=None)[0]
            x_u = m[u] + C[np.ix_(u, k)] @ sol
        else:
            x_u = m[u]
        block = out[frames][:, active]
        block[~Ma[frames] & in_gap.reshape(-1, ca)] = x_u
        out[np.ix_(frames, active)] = block
        for key, v in (("window_lengths", L), ("contexts", ctx), ("methods", method)):
            diag[key].append(v)
        if start == 0 or stop == T:
            issues.append(Issue("warning", "end_gap", f"gap at frames {start}–{stop - 1} touches the curve end: "
                                "conditioned on one side only (drifts toward the mean)", (f"frames {start}-{stop}",)))
    notes = [model[3] for model in models.values() if model[3]]
    if notes:
        issues.insert(0, Issue("warning", "autocovariance_fallback", "too few fully-known windows (" + ", ".join(notes)
                               + "): used a regularised autocovariance estimate instead"))
    if constant:
        issues.append(Issue("info", "constant_channel", f"channel(s) {constant} are constant: filled with the "
                            "constant", tuple(f"channel {j}" for j in constant)))
    used = sorted(set(diag["methods"]))
    diag["method"] = "+".join(used) if used else ("constant" if constant else "none")
    n_u = int((~M).sum())
    message = (f"filled {n_u} unknown sample(s) in {len(gaps)} gap(s) by the Gaussian conditional mean "
               f"({diag['method']})" if gaps else f"filled {n_u} unknown sample(s)")
    message = "; ".join([message] + [i.message for i in issues])
    issues.sort(key=lambda i: i.severity != "warning")
    status = 1 if any(i.severity == "warning" for i in issues) else 0
    return Result(value=out[:, 0] if one_d else out, status=status, message=message, diagnostics=diag, issues=issues)


def context_channels(values, target: int, known, gap_length: int, window: int = None) -> np.ndarray:
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
    ndarray of int
        Column indices, ``target`` first, then the chosen channels by decreasing correlation.
    """
    X = np.asarray(values, dtype=np.float64)
    if X.ndim != 2 or not 0 <= int(target) < X.shape[1]:
        raise ShapeSpaceError(f"values must have shape (T, c) and target a column of it, got {X.shape}, {target}",
                              "shape")
    M = np.asarray(known, dtype=bool)
    if M.shape != (X.shape[0],):
        raise ShapeSpaceError(f"known must have shape ({X.shape[0]},), got {M.shape}", "shape")
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
