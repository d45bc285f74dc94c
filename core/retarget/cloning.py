"""Expression cloning and retargeting (thesis ch. 5 and 3.5).

- :func:`copy_weights` — corresponding parameterisation (3.5.3): mapped
  channels copied with per-channel gain and offset.
- :func:`cloning_matrix` — linear expression cloning ``W_t ≈ W_s E`` from
  c ≥ n corresponding pose pairs (3.5.3); :func:`key_poses` — Chuang–Bregler
  key-pose selection (largest / smallest projections on the leading
  principal components).
- :func:`fit_frames` — per-frame bounded least squares of target sliders to
  source positions at corresponding points.
- :func:`spacetime` — space-time cloning (ch. 5): match temporal derivatives
  ``D S ≈ D (B W)`` at corresponding points, first and last frames fixed,
  regulariser ``λ Σ_k (w_k / σ_k)²``; decoupled by an eigendecomposition of
  the small n × n target Gram matrix into one tridiagonal solve per mode, and
  optionally bounded by a projected Newton method around that fast solve.
- :func:`reduce_keys` — optimal key reduction under a max-error tolerance.
- :func:`procrustes`, :func:`landmark_warp` — rigid stabilisation and
  correspondence between different topologies (3.5.4).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import lapack, solveh_banded
from scipy.optimize import linprog

from ..boxqp import solve_box_qp
from ..result import ShapeSpaceError

__all__ = ["copy_weights", "cloning_matrix", "key_poses", "fit_frames", "spacetime", "SpacetimeResult",
           "reduce_keys", "reduce_keys_bezier", "curve_slopes", "hermite", "procrustes", "landmark_warp", "landmark_layout", "check_landmarks",
           "peak_landmarks", "closest_points"]


def copy_weights(source, mapping, n_target, gain=None, offset=None, lo=None, hi=None) -> np.ndarray:
    """Copy mapped channels: ``w_t[:, j] = gain_j · w_s[:, i] + offset_j`` for each pair (i, j).

    Parameters
    ----------
    source : ndarray (f, n_s)
    mapping : sequence of (source index, target index)
    n_target : int
    gain, offset : ndarray (n_target,), optional
    lo, hi : ndarray (n_target,), optional
        Clamp to the target sliders' ranges.
    """
    S = np.asarray(source, dtype=np.float64)
    if not mapping:
        raise ShapeSpaceError("source and target share no mapped channels", "no_mapping")
    out = np.zeros((S.shape[0], n_target))
    g = np.ones(n_target) if gain is None else np.asarray(gain, dtype=np.float64)
    o = np.zeros(n_target) if offset is None else np.asarray(offset, dtype=np.float64)
    for i, j in mapping:
        out[:, j] = g[j] * S[:, i] + o[j]
    if lo is not None or hi is not None:
        out = np.clip(out, -np.inf if lo is None else lo, np.inf if hi is None else hi)
    return out


def cloning_matrix(source_poses, target_poses, ridge: float = 1e-8) -> np.ndarray:
    """Linear expression cloning matrix ``E`` (n_s × n_t) with ``W_t ≈ W_s E`` (3.5.3).

    Needs c ≥ n_s corresponding pose pairs (rows); solved in least squares
    with a tiny ridge so rank-deficient pairs still give the minimum-norm map.
    """
    Ws = np.asarray(source_poses, dtype=np.float64)
    Wt = np.asarray(target_poses, dtype=np.float64)
    if Ws.ndim != 2 or Wt.ndim != 2 or Ws.shape[0] != Wt.shape[0]:
        raise ShapeSpaceError(f"pose pairs must be (c, n_s) and (c, n_t) with equal c; got {Ws.shape}, {Wt.shape}",
                              "shape")
    if Ws.shape[0] < Ws.shape[1]:
        raise ShapeSpaceError(f"{Ws.shape[0]} pose pairs cannot determine a map from {Ws.shape[1]} source "
                              "channels; give at least as many pairs as source channels", "too_few")
    A = Ws.T @ Ws
    return np.linalg.solve(A + ridge * np.trace(A) / max(A.shape[0], 1) * np.eye(A.shape[0]), Ws.T @ Wt)


def key_poses(weights, components: int = 3) -> np.ndarray:
    """Chuang–Bregler key poses: frames with the largest and smallest projection on each leading PC."""
    W = np.asarray(weights, dtype=np.float64)
    centred = W - W.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    proj = centred @ vt[:components].T
    picks = []
    for j in range(proj.shape[1]):
        for k in (int(np.argmax(proj[:, j])), int(np.argmin(proj[:, j]))):
            if k not in picks:
                picks.append(k)
    return np.array(picks, dtype=int)


def fit_frames(B, neutral, frames, lo, hi, reg: float = 1e-6) -> np.ndarray:
    """Per-frame bounded least squares: ``min ‖B w − (s_f − b0)‖² + reg·(tr(BᵀB)/n)·‖w‖²``, lo ≤ w ≤ hi.

    The regulariser is relative to the mean diagonal of ``BᵀB`` (so results do
    not depend on units) and floored at 1e-10 of it for a well-posed QP; a frame
    the QP solver cannot finish is solved again with scipy's bounded least
    squares (BVLS).

    Parameters
    ----------
    B : ndarray (3m, n)
        Target delta-matrix rows at the corresponding points.
    neutral : ndarray (3m,)
    frames : ndarray (f, 3m)
        Source positions at the corresponding points, per frame.
    """
    B, S = np.asarray(B, dtype=np.float64), np.asarray(frames, dtype=np.float64)
    rhs = S - np.asarray(neutral, dtype=np.float64)
    G = B.T @ B
    scale = max(np.trace(G) / G.shape[0], 1e-300)
    a = max(reg, 1e-10) * scale
    lam, Q = np.linalg.eigh(G)
    keep = lam > 1e-12 * lam.max()
    V, s = Q[:, keep], lam[keep]
    out = np.empty((S.shape[0], B.shape[1]))
    x = np.clip(np.zeros(B.shape[1]), lo, hi)
    for f in range(S.shape[0]):
        g = B.T @ rhs[f]
        res = solve_box_qp(2 * a, V, 2 * s, 2 * g, lo, hi, x0=x)
        if res.status != 0 and res.residual > 1e-7 * max(1.0, 2 * float(np.abs(g).max())):
            from scipy.optimize import lsq_linear
            A = np.vstack([B, np.sqrt(a) * np.eye(B.shape[1])])
            b = np.concatenate([rhs[f], np.zeros(B.shape[1])])
            res_x = lsq_linear(A, b, bounds=(lo, hi), method="bvls", tol=1e-12).x
        else:
            res_x = res.x
        x = res_x
        out[f] = x
    return out


@dataclass
class SpacetimeResult:
    weights: np.ndarray        # (f, n)
    iterations: int            # outer (projected Newton) iterations, 0 unbounded
    status: int
    message: str
    diagnostics: dict = field(default_factory=dict)


#: Largest banded-Cholesky Newton step (≈ flops, f·n·(2n)²) before bounded space-time falls back to CG.
BANDED_FLOP_LIMIT = 4e9


def spacetime(B, neutral, frames, sigma, lam: float = 1e-3, first=None, last=None, lo=None, hi=None,
              tol: float = 1e-8, max_iter: int = 100, relative: bool = False,
              max_exact_active: int = 1000) -> SpacetimeResult:
    """Space-time expression cloning (thesis ch. 5), optionally with slider bounds.

    Minimises ``‖D (W Bᵀ − S)‖² + λ Σ_f Σ_k (w_fk / σ_k)²`` over the interior
    frames, with ``W[0] = first`` and ``W[-1] = last`` fixed (default: the
    per-frame fits of the end frames), where ``S`` are the source positions
    at the corresponding points relative to the target neutral and ``D`` the
    temporal first difference.

    Decoupling: with ``W = Y Σ`` and ``Σ Bᵀ B Σ = Q diag(μ) Qᵀ`` the normal
    equations ``DᵀD Y (ΣBᵀBΣ) + λ Y = DᵀD S B Σ`` split into one tridiagonal
    system ``(μ_j DᵀD + λ I) z_j = r_j`` per mode (factored once) — O(n·f)
    per solve after an O(n³) eigendecomposition, no Kronecker system.

    Bounds (lo ≤ w ≤ hi), around the fast solve: a primal–dual active-set
    iteration (Hintermüller–Ito–Kunisch) fixes the entries at or beyond a
    bound, solves exactly for the rest and updates the set from the
    multipliers' signs until it repeats, which is the exact KKT point; on
    cycling a projected Newton method with an ε-active set and a projected
    Armijo search (monotone) takes over.  Each reduced Newton system
    ``𝓗_FF d_F = r_F`` is solved exactly by the cheapest route: few active
    entries m — the m × m capacitance system ``(E_Aᵀ 𝓗⁻¹ E_A) ν = −(𝓗⁻¹ r)_A``,
    whose entries are lookups in two tables of per-mode Green's functions of
    the Dirichlet second difference (closed form, exact), solved directly and
    refined against exact products — two decoupled solves a step; many — a banded Cholesky
    of 𝓗 with the active rows replaced by the identity (bandwidth 2n − 1
    frame-major, O(f n³)); beyond ``BANDED_FLOP_LIMIT`` — CG preconditioned
    by the unbounded inverse.  Convergence test: the natural residual
    ``‖y − clip(y − ∇f(y))‖∞ ≤ tol · max(1, ‖rhs‖∞)`` in the whitened
    variables (zero exactly at the KKT point), or no further decrease at a
    residual ≤ 1e-6 (rounding).  The weights satisfy the bounds exactly.

    Parameters
    ----------
    B : ndarray (3m, n)
    neutral : ndarray (3m,)
    frames : ndarray (f, 3m)
    sigma : ndarray (n,)
        Per-slider scale σ_k (e.g. standard deviations of training weights, 5.5).
    relative : bool
        Read ``lam`` relative to the data: λ · mean eigenvalue of ``ΣBᵀBΣ``
        (unit-free; used by the retarget command).
    max_exact_active : int
        Largest active set for which a Newton step uses the capacitance
        system (cost O(m³) plus lookup tables of O(c²·f) for the c channels
        involved); larger ones use the banded Cholesky (or CG).
    """
    B = np.asarray(B, dtype=np.float64)
    S = np.asarray(frames)                       # not copied: only S·B is needed (memory for long shots)
    b0 = np.asarray(neutral, dtype=np.float64)
    F, n = S.shape[0], B.shape[1]
    if F < 3:
        raise ShapeSpaceError(f"space-time cloning needs at least 3 frames, got {F}", "too_short")
    sig = np.asarray(sigma, dtype=np.float64).reshape(n)
    if np.any(sig <= 0) or not np.isfinite(sig).all():
        raise ShapeSpaceError("sigma must be positive and finite for every slider", "range")
    bounded = lo is not None or hi is not None
    lo = np.full(n, -np.inf) if lo is None else np.asarray(lo, dtype=np.float64)
    hi = np.full(n, np.inf) if hi is None else np.asarray(hi, dtype=np.float64)
    if first is None or last is None:
        ends = fit_frames(B, b0, S[[0, -1]].astype(np.float64), lo if bounded else np.full(n, -1e6),
                          hi if bounded else np.full(n, 1e6))
        first = ends[0] if first is None else first
        last = ends[1] if last is None else last
    first, last = np.asarray(first, dtype=np.float64), np.asarray(last, dtype=np.float64)
    G = B.T @ B
    M = sig[:, None] * G * sig[None, :]
    mu, Q = np.linalg.eigh(M)
    mu = np.maximum(mu, 0.0)
    if relative:  # λ relative to the data's scale: the mean eigenvalue of ΣBᵀBΣ
        lam = lam * max(float(mu.mean()), 1e-300)
    # right-hand side DᵀD S B Σ, for all frames, then restricted to the interior
    Bs = B * sig
    SB = np.empty((F, n))                                             # (S − b0)·B·Σ, in row chunks
    offset = b0 @ Bs
    for start in range(0, F, 2048):
        rows = slice(start, min(start + 2048, F))
        SB[rows] = np.asarray(S[rows], dtype=np.float64) @ Bs - offset
    DtD_SB = np.empty_like(SB)
    DtD_SB[0] = SB[0] - SB[1]
    DtD_SB[-1] = SB[-1] - SB[-2]
    DtD_SB[1:-1] = 2 * SB[1:-1] - SB[:-2] - SB[2:]
    Yf, Yl = first / sig, last / sig

    def base_rhs():
        R = DtD_SB[1:-1].copy()
        # boundary frames moved to the right-hand side: DᵀD couples frame 1 to 0 and F−2 to F−1
        R[0] += (Yf @ M)
        R[-1] += (Yl @ M)
        return R

    # DᵀD on the interior (end frames fixed) is the Dirichlet second difference T = tridiag(−1, 2, −1), so
    # in the spatial eigenbasis Q every mode is one symmetric positive definite tridiagonal system
    # (μ_j T + λ I) z_j = r_j: factored once (LAPACK pttrf), then two O(f) sweeps per solve (pttrs).
    factors = []
    for j in range(n if F > 3 else 0):
        diag_j, off_j, info = lapack.dpttrf(np.full(F - 2, 2.0 * mu[j] + lam), np.full(F - 3, -mu[j]))
        if info:
            raise ShapeSpaceError("the space-time system is not positive definite (λ must be > 0)", "range")
        factors.append((diag_j, off_j))

    def solve_modes(rhs=None):
        """(DᵀD ⊗ M + λ I) y = rhs over the interior, decoupled per mode."""
        Rq = (base_rhs() if rhs is None else rhs) @ Q
        if F == 3:                                          # one interior frame: a diagonal system
            return (Rq / (2.0 * mu + lam)) @ Q.T
        Z = np.empty_like(Rq)
        for j, (diag_j, off_j) in enumerate(factors):
            Z[:, j] = lapack.dpttrs(diag_j, off_j, Rq[:, j])[0]
        return Z @ Q.T

    # Closed-form entries of 𝓗⁻¹ for the capacitance systems.  Per spatial mode j, (μ_j T + λ I)⁻¹ of the
    # Dirichlet second difference T has, with ρ_j = μ_j / (μ_j + λ/2 + s_j), s_j = √(λμ_j + λ²/4) and
    # 1-based frames s, l:  G_j(s, l) = [ρ^|s−l| + ρ^(2N+2−|s−l|) − ρ^(s+l) − ρ^(2N+2−s−l)] / D_j,
    # D_j = 2 s_j (1 − ρ^(2N+2)) — a function of |s − l| minus a function of s + l.  Summed over the modes
    # for each pair of channels once, every entry 𝓗⁻¹[(t,k),(t',k')] = Σ_j Q_kj Q_k'j G_j is a lookup.
    green = {}

    def green_tables(chans):
        """Tables V1[k, k', |Δt|] and V2[k, k', t + t' + 2] for (at least) the channels ``chans``."""
        if "chans" in green and np.isin(chans, green["chans"]).all():
            return green
        chans = np.union1d(chans, green.get("chans", np.zeros(0, int)))
        Ni = F - 2
        s_ = np.sqrt(lam * mu + 0.25 * lam * lam)
        rho = mu / (mu + 0.5 * lam + s_)
        pw = rho[:, None] ** np.arange(2 * Ni + 3)[None, :]                      # (n, 2N + 3)
        denom = (2.0 * s_ * (1.0 - pw[:, 2 * Ni + 2]))[:, None]
        d = np.arange(Ni)
        R1 = (pw[:, d] + pw[:, 2 * Ni + 2 - d]) / denom                          # (n, N): |Δt|
        sig_ = np.arange(2, 2 * Ni + 1)
        R2 = np.zeros((n, 2 * Ni + 1))
        R2[:, 2:] = (pw[:, sig_] + pw[:, 2 * Ni + 2 - sig_]) / denom              # (n, 2N + 1): t + t' + 2
        c = chans.size
        iu, ju = np.triu_indices(c)                           # the tables are symmetric in the channel pair
        QQ = Q[chans][iu] * Q[chans][ju]                      # (pairs, n)
        pair = np.empty((c, c), dtype=np.int32)
        pair[iu, ju] = pair[ju, iu] = np.arange(iu.size)
        pos = np.full(n, -1, dtype=np.int32)
        pos[chans] = np.arange(c)
        green.update(chans=chans, pos=pos, pair=pair, V1=(QQ @ R1).ravel(), V2=(QQ @ R2).ravel(),
                     n1=R1.shape[1], n2=R2.shape[1])
        return green

    def capacitance(active):
        """𝓗⁻¹ restricted to the active entries (m, m), float64, by table lookups."""
        t, k = np.divmod(active.astype(np.int32), np.int32(n))
        g = green_tables(np.unique(k))
        kk = g["pos"][k]
        pr = g["pair"][kk[:, None], kk[None, :]]                                  # (m, m) channel pair
        index = pr * np.int32(g["n1"])
        index += np.abs(t[:, None] - t[None, :])
        C = np.take(g["V1"], index)
        np.multiply(pr, np.int32(g["n2"]), out=index)
        index += t[:, None] + t[None, :] + np.int32(2)
        C -= np.take(g["V2"], index)
        return C                      # symmetric by construction (V1, V2 symmetric in the channel pair)

    def tables_fit(active) -> bool:
        c = np.unique(active % n).size
        return c * (c + 1) // 2 * 3 * (F - 2) <= 4e7           # ≤ 320 MB of lookup tables

    def assemble(Y_inner):
        W = np.empty((F, n))
        W[0], W[-1] = first, last
        W[1:-1] = Y_inner * sig
        if bounded:  # undo the rounding of the whitened bounds (lo/σ)·σ
            np.clip(W, lo, hi, out=W)
        return W

    Y = solve_modes()
    if not bounded:
        return SpacetimeResult(assemble(Y), 0, 0, "ok", {"modes": n})
    ylo = np.broadcast_to(lo / sig, Y.shape)
    yhi = np.broadcast_to(hi / sig, Y.shape)

    def hmul(Yv):
        """𝓗y = DᵀD y ΣBᵀBΣ + λ y over the interior frames (the boundary frames are fixed)."""
        T = 2.0 * Yv
        T[1:] -= Yv[:-1]
        T[:-1] -= Yv[1:]
        return T @ M + lam * Yv

    R0 = base_rhs()
    scale = max(1.0, float(np.abs(R0).max()))

    def objective(Yv):
        return 0.5 * float(np.sum(Yv * hmul(Yv))) - float(np.sum(R0 * Yv))

    # Projected Newton with an ε-active set (Bertsekas 1982) around the fast decoupled solve: on the
    # free entries the Newton system 𝓗_FF d = −g_F is solved by conjugate gradients preconditioned
    # with the exact inverse of the whole operator (one decoupled solve per iteration), inexactly
    # while far from the solution; a projected Armijo search keeps the iteration monotone.
    Y = np.clip(Y, ylo, yhi)
    f = objective(Y)
    solves, status, message = 0, 1, "iteration limit reached"

    band = {}

    def _full_band():
        """𝓗 in LAPACK upper band storage (frame-major: (t, k) → t·n + k), bandwidth u = 2n − 1."""
        if "ab" not in band:
            u = 2 * n - 1
            ab = np.zeros((u + 1, Y.size))
            j = np.arange(Y.size)
            tj, kj = np.divmod(j, n)
            for o in range(u + 1):
                i = j[o:] - o
                ti, ki = np.divmod(i, n)
                same = ti == tj[o:]
                vals = np.where(same, 2.0 * M[ki, kj[o:]] + lam * (o == 0),
                                np.where(tj[o:] == ti + 1, -M[ki, kj[o:]], 0.0))
                ab[u - o, o:] = vals
            band["ab"] = ab
        return band["ab"]

    def _banded_step(free, r):
        """Large active sets: the Newton system on the free entries, 𝓗_FF d_F = r_F, by a banded Cholesky.
        Frame-major, 𝓗 = DᵀD ⊗ M + λI couples an entry only to entries ≤ 2n − 1 places away; the active
        entries' rows and columns are replaced by the identity (d_A = 0), which keeps the band: O(f n³)."""
        nonlocal solves
        ab = _full_band().copy()
        u = ab.shape[0] - 1
        keep = free.ravel()
        ab *= keep                                               # active columns
        for o in range(1, u + 1):                                # active rows i = j − o
            ab[u - o, o:] *= keep[:-o]
        ab[u, ~keep] = 1.0
        solves += 1
        try:
            d = solveh_banded(ab, np.where(keep, r.ravel(), 0.0), lower=False, check_finite=False)
        except np.linalg.LinAlgError:
            return _pcg_free(free, np.where(free, r, 0.0), scale)
        return d.reshape(Y.shape)

    def _pcg_free(free, r, nat):
        """Large active sets: CG on the free entries, preconditioned by the exact unbounded inverse."""
        nonlocal solves
        forcing = min(0.1, np.sqrt(nat / scale))
        r_norm0 = float(np.linalg.norm(r))
        d = np.zeros_like(r)
        z = np.where(free, solve_modes(rhs=r), 0.0)
        solves += 1
        p_dir, rz = z.copy(), float(np.sum(r * z))
        for _ in range(200):
            Ap = np.where(free, hmul(p_dir), 0.0)
            alpha = rz / float(np.sum(p_dir * Ap))
            d += alpha * p_dir
            r = r - alpha * Ap
            if np.linalg.norm(r) <= forcing * r_norm0:
                break
            z = np.where(free, solve_modes(rhs=r), 0.0)
            solves += 1
            rz_new = float(np.sum(r * z))
            p_dir = z + (rz_new / rz) * p_dir
            rz = rz_new
        return d

    def _capacitance_step(active, r):
        """Newton step on the free entries with the active ones held: 𝓗 d = r + E_A ν, d_A = 0, i.e.
        the m × m capacitance system (E_Aᵀ 𝓗⁻¹ E_A) ν = −(𝓗⁻¹ r)_A, its matrix by closed-form lookups,
        solved directly and refined against exact products (one decoupled solve each)."""
        nonlocal solves
        d = solve_modes(rhs=r)
        solves += 1
        if not active.size:
            return d
        C = capacitance(active)

        def apply(v):                   # numpy's LU (refinement below rarely needs a second call)
            try:
                return np.linalg.solve(C, v)
            except np.linalg.LinAlgError:
                return np.linalg.lstsq(C, v, rcond=None)[0]

        def lifted_solve(v):                               # 𝓗⁻¹ E_A v, full (inner, n)
            nonlocal solves
            lift = np.zeros(Y.size)
            lift[active] = v
            solves += 1
            return solve_modes(rhs=lift.reshape(Y.shape))

        b = -d.ravel()[active]
        b_norm = float(np.linalg.norm(b))
        nu = apply(b)
        X = lifted_solve(nu)
        for _ in range(5):                                 # iterative refinement on the exact products
            res = b - X.ravel()[active]
            if np.linalg.norm(res) <= 1e-12 * b_norm:
                break
            delta = apply(res)
            X += lifted_solve(delta)
        d += X
        d.ravel()[active] = 0.0
        return d

    def reduced_step(act, r):
        """Exact Newton step on the free entries (𝓗_FF d_F = r_F, d_A = 0), by the cheapest route."""
        active = np.flatnonzero(act)
        if active.size <= max_exact_active and tables_fit(active):
            return _capacitance_step(active, r)
        if Y.size * (2 * n) ** 2 <= BANDED_FLOP_LIMIT and Y.size * 2 * n <= BANDED_FLOP_LIMIT / 100:
            return _banded_step(~act, r)
        return _pcg_free(~act, np.where(act, 0.0, r), 0.0)

    # Primal–dual active set (Hintermüller–Ito–Kunisch): fix the entries whose bound is active or
    # violated, solve exactly for the rest, and repeat with the multipliers' signs until the active
    # set repeats — then the KKT conditions hold exactly.  Usually a handful of reduced solves; on
    # cycling or no progress the globalised projected Newton loop below takes over.
    upper, lower = Y >= yhi, Y <= ylo
    seen = set()
    it = 0
    for it in range(1, max_iter + 1):
        Yn = np.where(upper, yhi, np.where(lower, ylo, Y))
        act = upper | lower
        Yn = Yn + reduced_step(act, R0 - hmul(Yn))
        mult = R0 - hmul(Yn)                                     # −∇f: > 0 pushes up, < 0 pushes down
        new_upper = np.where(act, upper & (mult > 0), Yn > yhi)
        new_lower = np.where(act, lower & (mult < 0), Yn < ylo)
        Y = Yn
        if np.array_equal(new_upper, upper) and np.array_equal(new_lower, lower):
            break
        key = hash(np.packbits(new_upper).tobytes() + np.packbits(new_lower).tobytes())
        if key in seen:
            break                                                # cycling: globalise below
        seen.add(key)
        upper, lower = new_upper, new_lower
    pdas_iterations = it
    Y = np.clip(Y, ylo, yhi)
    f = objective(Y)

    for it in range(1, max_iter + 1):
        g = hmul(Y) - R0
        nat = float(np.abs(Y - np.clip(Y - g, ylo, yhi)).max())
        if nat <= tol * scale:
            status, message = 0, "converged"
            break
        eps = min(1e-3, nat)
        act = ((Y <= ylo + eps) & (g > 0)) | ((Y >= yhi - eps) & (g < 0))
        free = ~act
        r = np.where(free, -g, 0.0)
        d = reduced_step(act, r)
        d = np.where(act, -g / (4.0 * float(mu.max()) + lam), d)
        step = 1.0
        while True:
            Yt = np.clip(Y + step * d, ylo, yhi)
            ft = objective(Yt)
            if ft <= f - 1e-4 * float(np.sum(g * (Y - Yt))) or step < 1e-10:
                break
            step *= 0.5
        if ft >= f:
            status, message = (0, "converged (rounding limit)") if nat <= 1e-6 * scale else (1, "stalled")
            break
        Y, f = Yt, ft
    return SpacetimeResult(assemble(Y), pdas_iterations + it - 1, status, message,
                           {"natural_residual": nat, "solves": solves, "active_set_iterations": pdas_iterations,
                            "newton_iterations": it - 1})


def _check_curve(times, values, tol):
    """Validated (times, values) as float64 (f,) and a non-negative tolerance."""
    t = np.asarray(times, dtype=np.float64).ravel()
    v = np.asarray(values, dtype=np.float64).ravel()
    if t.size != v.size or t.size < 1:
        raise ShapeSpaceError("times and values must be non-empty and of equal length", "shape")
    if tol < 0:
        raise ShapeSpaceError(f"tol must be non-negative, got {tol}", "range")
    return t, v


def reduce_keys(times, values, tol: float):
    """Fewest keys (a subset of the samples) whose linear interpolation stays within ``tol`` (3.5.5).

    Exact dynamic programming (a shortest path over valid segments); a
    segment i→j is valid when the line through samples i and j is within
    ``tol`` of every sample between, tested in O(1) per step by narrowing the
    feasible slope interval from i.  Endpoints are always kept.

    Returns
    -------
    ndarray of int
        Indices of the kept samples.
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
    keep = [n - 1]
    while keep[-1] != 0:
        keep.append(prev[keep[-1]])
    return np.array(keep[::-1])


def curve_slopes(times, values) -> np.ndarray:
    """Slope of the dense curve at every sample: the derivative of the parabola through each sample
    and its two neighbours (one-sided at the ends), shape (f,)."""
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


def hermite(times, values, slopes, t) -> np.ndarray:
    """Piecewise cubic Hermite through keys ``(times, values)`` with ``slopes`` at ``t`` — exactly what
    Blender evaluates for Bézier keys whose handles sit at 1/3 of each segment along the slope."""
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


def _segment_basis(t0, t1, ts):
    """Hermite basis on [t0, t1] at ``ts``: columns multiply (v0, m0, v1, m1), shape (len(ts), 4)."""
    h = t1 - t0
    s = (ts - t0) / h
    return np.column_stack([(1 + 2 * s) * (1 - s) ** 2, h * s * (1 - s) ** 2, s * s * (3 - 2 * s), h * s * s * (s - 1)])


def _fit_two_keys(A, y):
    """Least-squares values and slopes of two keys, with the max error ``‖A x − y‖∞`` they leave."""
    x = np.linalg.lstsq(A, y, rcond=None)[0]
    return x, float(np.abs(A @ x - y).max())


def _minimax_two_keys(A, y):
    """Values and slopes minimising the max error exactly (a small linear program, HiGHS)."""
    k = A.shape[1]
    ones = np.ones((y.size, 1))
    res = linprog(np.r_[np.zeros(k), 1.0], A_ub=np.block([[A, -ones], [-A, -ones]]), b_ub=np.r_[y, -y],
                  bounds=[(None, None)] * k + [(0, None)], method="highs")
    return (res.x[:k], float(res.x[k])) if res.status == 0 else (None, np.inf)


def reduce_keys_bezier(times, values, tol: float, max_span: int = 128, refine: bool = True):
    """Fewest smooth Bézier keys (aligned handles) whose curve stays within ``tol`` (3.5.5).

    Two stages.  (1) Exact dynamic programming over subsets of the samples
    when each kept sample keeps its value and the dense curve's slope there
    (:func:`curve_slopes`): every segment is then a cubic Hermite fixed by its
    ends, segments are independent, and the fewest keys is a shortest path
    over the valid segments (searched up to ``max_span`` samples long).
    (2) ``refine``: sweep the keys and drop each one whose two neighbours can
    absorb it — their values and slopes refitted (least squares, else the
    minimax linear program) so that the max error over the samples they
    govern stays within ``tol`` — until no key can go.  Stage 2 is what curve
    fitters like Blender's Decimate do; starting it from the optimal
    interpolating solution gives fewer keys at the same max error.

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
    best = np.full(n, np.iinfo(np.int64).max)
    prev = np.full(n, -1)
    best[0] = 1
    offs = np.arange(1, max_span + 1)
    for i in range(n - 1):
        if best[i] == np.iinfo(np.int64).max:
            continue
        js = i + offs[offs < n - i]                                  # candidate ends (L,)
        h = t[js] - t[i]
        ks = np.arange(i + 1, js[-1])                                # interior samples of the longest
        if ks.size:
            s = (t[ks][None, :] - t[i]) / h[:, None]                 # (L, K)
            inside = s < 1.0 - 1e-12
            h00, h10 = (1 + 2 * s) * (1 - s) ** 2, s * (1 - s) ** 2
            h01, h11 = s * s * (3 - 2 * s), s * s * (s - 1)
            curve = (h00 * v[i] + h10 * (h * m[i])[:, None] + h01 * v[js][:, None]
                     + h11 * (h * m[js])[:, None])
            err = np.where(inside, np.abs(curve - v[ks][None, :]), 0.0).max(axis=1)
        else:
            err = np.zeros(js.size)
        ok = js[(err <= tol) & (best[i] + 1 < best[js])]
        best[ok] = best[i] + 1
        prev[ok] = i
    keep = [n - 1]
    while keep[-1] != 0:
        keep.append(prev[keep[-1]])
    idx = keep[::-1]
    kv, km = list(v[idx]), list(m[idx])
    if refine:
        _absorb_keys(t, v, idx, kv, km, tol)
    return np.array(idx), np.array(kv), np.array(km)


def _absorb_keys(t, v, idx, kv, km, tol, max_sweeps: int = 4):
    """Stage 2 of :func:`reduce_keys_bezier`, in place on the key lists."""
    for _ in range(max_sweeps):
        changed, p = False, 1
        while p < len(idx) - 1:
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
            A, y = np.vstack(blocks), np.concatenate(rhs)
            x, err = _fit_two_keys(A, y)
            if err > tol:
                x, err = _minimax_two_keys(A, y)
            if err <= tol * (1 - 1e-6):
                kv[p - 1], km[p - 1], kv[p + 1], km[p + 1] = x
                del idx[p], kv[p], km[p]
                changed = True
            else:
                p += 1
        if not changed:
            return


def procrustes(source, target, scaling: bool = True):
    """Best similarity transform ``target ≈ s·R·source + t`` (Umeyama); returns (s, R, t)."""
    X = np.asarray(source, dtype=np.float64)
    Y = np.asarray(target, dtype=np.float64)
    if X.shape != Y.shape or X.ndim != 2 or X.shape[1] != 3:
        raise ShapeSpaceError(f"point sets must both be (m, 3); got {X.shape}, {Y.shape}", "shape")
    if X.shape[0] < 3:
        raise ShapeSpaceError("at least 3 points are needed for a rigid alignment", "too_few")
    mx, my = X.mean(axis=0), Y.mean(axis=0)
    Xc, Yc = X - mx, Y - my
    if np.linalg.matrix_rank(Xc, tol=1e-9 * (np.abs(Xc).max() + 1e-300)) < 2:
        raise ShapeSpaceError("the points are collinear: a rotation is not determined", "collinear")
    U, sv, Vt = np.linalg.svd(Yc.T @ Xc)
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.diag([1.0, 1.0, d])
    R = U @ D @ Vt
    s = float(np.trace(np.diag(sv) @ D) / np.sum(Xc ** 2)) if scaling else 1.0
    return s, R, my - s * R @ mx


def landmark_layout(landmarks, rel_tol: float = 1e-3) -> str:
    """``"collinear"``, ``"coplanar"`` or ``"spatial"``: the spread of landmark points (m, 3), judged by
    the singular values of the centred points relative to the largest."""
    X = np.asarray(landmarks, dtype=np.float64)
    sv = np.linalg.svd(X - X.mean(axis=0), compute_uv=False)
    if sv.size < 2 or sv[1] <= rel_tol * sv[0]:
        return "collinear"
    if sv.size < 3 or sv[2] <= rel_tol * sv[0]:
        return "coplanar"
    return "spatial"


def check_landmarks(source_landmarks, target_landmarks):
    """Validate landmark pairs: equal (m, 3) shapes, m ≥ 3, not collinear on either side.

    Returns the two arrays (float64) and their layouts (:func:`landmark_layout`)."""
    src = np.asarray(source_landmarks, dtype=np.float64)
    dst = np.asarray(target_landmarks, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise ShapeSpaceError(f"source_landmarks and target_landmarks must both have shape (m, 3), got "
                              f"{src.shape} and {dst.shape}", "shape")
    if src.shape[0] < 3:
        raise ShapeSpaceError(f"a landmark warp needs at least 3 landmark pairs, got {src.shape[0]}", "too_few")
    layouts = (landmark_layout(src), landmark_layout(dst))
    if "collinear" in layouts:
        raise ShapeSpaceError("the landmarks lie on a line: add landmarks off that line (e.g. eye corners and "
                              "the chin, not only the mouth)", "collinear")
    return src, dst, layouts


def landmark_warp(source_landmarks, target_landmarks, points):
    """Warp ``points`` (p, 3) so the source landmarks land on the target ones (3.5.4).

    A similarity (Procrustes) aligns the landmark sets, then a thin-plate RBF
    carries the residual so every landmark lands exactly.  Needs at least 3
    landmark pairs, not collinear on either mesh; with coplanar landmarks
    (all on the face's front, or only 3) the residual warp uses the 3-D
    biharmonic kernel ``r`` with a constant, which they determine, instead of
    thin plates with an affine part, which they do not.
    """
    from ..rbf import fit_rbf
    src, dst, layouts = check_landmarks(source_landmarks, target_landmarks)
    s, R, t = procrustes(src, dst)
    aligned = s * src @ R.T + t
    if layouts == ("spatial", "spatial") and src.shape[0] >= 5:
        warp = fit_rbf(aligned, dst - aligned, "thin_plate_spline", 1.0, 1)
    else:   # the 3-D biharmonic kernel r only needs a constant, which any ≥ 1 landmarks determine
        warp = fit_rbf(aligned, dst - aligned, "linear", 1.0, 0)
    moved = s * np.asarray(points, dtype=np.float64) @ R.T + t
    return moved + warp(moved)


def peak_landmarks(source_deltas, target_deltas, pairs, rel_tol: float = 0.05):
    """Landmark pairs from matching shapes: for each mapped pair (i, j) the vertex that shape i moves most
    on the source and shape j on the target (e.g. jawOpen → chin, eyeBlink → lid, mouthSmile → corner).

    Parameters
    ----------
    source_deltas : ndarray (n_s, p_s, 3)
    target_deltas : ndarray (n_t, p_t, 3)
    pairs : sequence of (source index, target index)
    rel_tol : float
        Shapes whose peak displacement is below ``rel_tol`` × the rig's largest are skipped (empty or
        faint shapes have no meaningful peak).

    Returns
    -------
    src, dst : ndarray of int (m,)
        Vertex indices, one pair per usable shape pair, each source and target vertex used once.
    used : list of (source index, target index)
        The shape pairs the landmarks come from.
    """
    ds = np.linalg.norm(np.asarray(source_deltas, dtype=np.float64), axis=2)     # (n_s, p_s)
    dt = np.linalg.norm(np.asarray(target_deltas, dtype=np.float64), axis=2)
    src, dst, used = [], [], []
    top_s, top_t = ds.max(initial=0.0), dt.max(initial=0.0)
    for i, j in pairs:
        a, b = int(np.argmax(ds[i])), int(np.argmax(dt[j]))
        if ds[i, a] < rel_tol * top_s or dt[j, b] < rel_tol * top_t or a in src or b in dst:
            continue
        src.append(a)
        dst.append(b)
        used.append((i, j))
    return np.array(src, dtype=int), np.array(dst, dtype=int), used


def closest_points(points, surface_points):
    """Index of the nearest ``surface_points`` row for each of ``points`` (dense correspondence)."""
    from scipy.spatial import cKDTree
    dist, idx = cKDTree(np.asarray(surface_points, dtype=np.float64)).query(np.asarray(points, dtype=np.float64))
    return idx, dist
