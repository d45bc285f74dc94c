"""Space-time expression cloning (thesis ch. 5): match the source motion's velocities, within slider bounds.

Problem.  With ``B`` (3m × n) the target's delta matrix at m corresponding
points, ``S`` (f × 3m) the source positions there relative to the target
neutral, ``D`` the temporal first difference and ``σ_k`` per-slider scales,
find the weights ``W`` (f × n) minimising the velocity mismatch (ch. 5)::

    ‖D (W Bᵀ − S)‖² + λ Σ_f Σ_k (w_fk / σ_k)²,     lo ≤ w_fk ≤ hi,

over the interior frames, the first and last frames fixed.  Matching
derivatives rather than positions keeps the *shape* of the motion where the
target cannot follow it (a slider at its limit), instead of clipping it.

Unbounded solve.  Whitening ``W = Y Σ`` and the eigendecomposition
``Σ BᵀB Σ = Q diag(μ) Qᵀ`` of the small n × n Gram matrix turn the normal
equations ``DᵀD Y M + λ Y = DᵀD S B Σ`` (``M = Σ BᵀB Σ``) into one symmetric
tridiagonal system ``(μ_j T + λ I) z_j = r_j`` per mode, ``T`` the Dirichlet
second difference: factored once (LAPACK ``pttrf``), O(f·n) per solve after an
O(n³) eigendecomposition — no Kronecker system is ever formed.  The interior
operator is ``𝓗 = DᵀD ⊗ M + λ I``.

Bounds.  A primal–dual active-set method (Hintermüller–Ito–Kunisch): fix the
entries whose bound is active or violated, solve *exactly* for the rest and
update the set from the multipliers' signs until it repeats — then the KKT
conditions hold exactly.  Each reduced Newton system ``𝓗_FF d_F = r_F``
(``d_A = 0``) is solved exactly by the cheapest route (:func:`reduced_step`):

- few active entries — the m × m capacitance system
  ``(E_Aᵀ 𝓗⁻¹ E_A) ν = −(𝓗⁻¹ r)_A``, whose entries are lookups in tables of
  closed-form per-mode Green's functions of ``T`` (:class:`GreenTables`),
  refined against exact products (:func:`capacitance_step`);
- many — a banded Cholesky of ``𝓗`` with the active rows replaced by the
  identity (bandwidth 2n − 1 frame-major, O(f n³); :func:`banded_step`);
- beyond :data:`BANDED_FLOP_LIMIT` — conjugate gradients preconditioned by
  the unbounded inverse (:func:`cg_step`).

If the active set cycles, a projected Newton method with an ε-active set and
a projected Armijo search (Bertsekas 1982; monotone) takes over
(:func:`projected_newton`).  Convergence test: the natural residual
``‖y − clip(y − ∇f(y))‖∞ ≤ tol · max(1, ‖rhs‖∞)`` in the whitened variables
(zero exactly at the KKT point), or no further decrease at a residual ≤ 1e-6
(rounding).  The returned weights satisfy the bounds exactly.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.linalg import lapack, solveh_banded

from ..errors import ErrorCode
from ..result import Result, ShapeSpaceError, Status
from ..validate import array, finite_scalar, positive
from .perframe import fit_frames

__all__ = ["spacetime", "DRIFT_BETA", "SpacetimeResult", "SpacetimeSystem", "GreenTables", "BANDED_FLOP_LIMIT",
           "reduced_step", "capacitance_step", "banded_step", "cg_step", "active_set", "projected_newton"]

#: Largest banded-Cholesky Newton step (≈ flops, f·n·(2n)²) before bounded space-time falls back to CG.
BANDED_FLOP_LIMIT = 4e9

#: Largest Green's-function lookup tables (entries, 8 bytes each: ≤ 320 MB) the capacitance route may build.
GREEN_TABLE_LIMIT = 4e7

#: Source rows multiplied at a time when forming ``S B Σ`` (the source is never copied as a whole).
CHUNK_ROWS = 2048

#: Default β of the retarget command's space-time method (position term, per frame²; #11).
DRIFT_BETA = 1e-3


@dataclass(kw_only=True)
class SpacetimeResult(Result):
    """Weights of a space-time solve (``value``, alias :attr:`weights`, shape (f, n)).

    ``iterations`` counts the bounded solver's outer iterations (active-set
    plus projected-Newton; 0 without bounds).  ``status`` is ``OK`` when the
    natural residual met the tolerance (or stopped decreasing at rounding
    level), ``NOT_CONVERGED`` at the iteration limit or when it stalled.
    ``diagnostics``: ``modes`` (unbounded) or ``natural_residual``, ``solves``,
    ``active_set_iterations``, ``newton_iterations`` (bounded).
    """

    @property
    def weights(self) -> np.ndarray:
        """The weights (f, n), including the fixed first and last frames."""
        return self.value


@dataclass
class GreenTables:
    """Entries of ``𝓗⁻¹`` for the capacitance systems, as lookups (per pair of channels).

    Per spatial mode j, ``(μ_j T + λ I)⁻¹`` of the Dirichlet second difference
    ``T`` (N = f − 2 interior frames) has, with ``ρ_j = μ_j / (μ_j + λ/2 + s_j)``,
    ``s_j = √(λμ_j + λ²/4)`` and 1-based frames s, l::

        G_j(s, l) = [ρ^|s−l| + ρ^(2N+2−|s−l|) − ρ^(s+l) − ρ^(2N+2−s−l)] / D_j,
        D_j = 2 s_j (1 − ρ^(2N+2))

    — a function of ``|s − l|`` minus a function of ``s + l``.  Summed over the
    modes once per pair of channels, every entry
    ``𝓗⁻¹[(t,k),(t',k')] = Σ_j Q_kj Q_k'j G_j`` is ``V1[pair, |t − t'|] − V2[pair, t + t' + 2]``.

    Attributes
    ----------
    chans : ndarray of int (c,)
        Channels covered.
    pos : ndarray of int32 (n,)
        Position of each channel in ``chans`` (−1 when absent).
    pair : ndarray of int32 (c, c)
        Row of each (symmetric) channel pair in the flattened tables.
    V1, V2 : ndarray, flattened (pairs · n1,), (pairs · n2,)
        The ``|Δt|`` and ``t + t' + 2`` tables.
    n1, n2 : int
        Their row lengths.
    """

    chans: np.ndarray
    pos: np.ndarray
    pair: np.ndarray
    V1: np.ndarray
    V2: np.ndarray
    n1: int
    n2: int


class SpacetimeSystem:
    """The interior operator ``𝓗 = DᵀD ⊗ M + λ I`` of one space-time problem, factored once.

    Built from the target's delta matrix, the slider scales, λ and the number
    of frames: the eigendecomposition ``M = Σ BᵀB Σ = Q diag(μ) Qᵀ`` and one
    LAPACK ``pttrf`` factor of ``μ_j T + λ I`` per mode.  Offers the exact
    decoupled solve (:meth:`solve`), products (:meth:`apply`), and — built on
    first use and kept as attributes — the Green's-function tables
    (:attr:`green`) and the band of ``𝓗`` (:attr:`band`) for the bounded steps.

    Parameters
    ----------
    B : ndarray (3m, n)
    sigma : ndarray (n,)
        Positive slider scales σ_k.
    lam : float
        λ (absolute, or relative to the mean eigenvalue of ``M`` when ``relative``).
    frame_count : int
        f ≥ 3 (the unknowns are the f − 2 interior frames).
    relative : bool

    Attributes
    ----------
    shape : tuple
        ``(f − 2, n)``: the interior unknowns.
    M : ndarray (n, n)
    mu : ndarray (n,)
        Eigenvalues of ``M``, clamped at 0.
    Q : ndarray (n, n)
    lam : float
        The absolute λ in use.
    factors : list of (ndarray, ndarray)
        Per mode, the ``pttrf`` factor (d, e) of ``μ_j T + λ I`` (empty for f = 3: a diagonal system).
    solves : int
        Decoupled solves made by the bounded steps (a diagnostic counter).
    green : GreenTables or None
        Cache of :meth:`green_tables`.
    band : ndarray or None
        Cache of :meth:`banded`.
    """

    def __init__(self, B: np.ndarray, sigma: np.ndarray, lam: float, frame_count: int, relative: bool = False,
                 beta: float = 0.0):
        self.B, self.sigma = B, sigma
        self.frame_count, self.n = int(frame_count), B.shape[1]
        self.shape = (self.frame_count - 2, self.n)
        G = B.T @ B
        self.M = sigma[:, None] * G * sigma[None, :]
        mu, self.Q = np.linalg.eigh(self.M)
        self.mu = np.maximum(mu, 0.0)
        if relative:  # λ relative to the data's scale: the mean eigenvalue of ΣBᵀBΣ
            lam = lam * max(float(self.mu.mean()), 1e-300)
        self.lam = lam
        self.beta = float(beta)
        self.lam_modes = lam + self.beta * self.mu      # per-mode shift: μ_j (T + β I) + λ = μ_j T + (λ + β μ_j)
        self.factors = [self._factor(j) for j in range(self.n if self.frame_count > 3 else 0)]
        self.solves = 0
        self.green: GreenTables | None = None
        self.band: np.ndarray | None = None

    def _factor(self, j: int) -> tuple:
        """LAPACK ``pttrf`` of ``μ_j (T + β I) + λ I`` (f − 2 interior frames)."""
        F, mu, lam = self.frame_count, self.mu, self.lam_modes[j]
        diag_j, off_j, info = lapack.dpttrf(np.full(F - 2, 2.0 * mu[j] + lam), np.full(F - 3, -mu[j]))
        if info:
            raise ShapeSpaceError("the space-time system is not positive definite (λ must be > 0)", "range")
        return diag_j, off_j

    def rhs(self, frames: np.ndarray, neutral: np.ndarray, first: np.ndarray, last: np.ndarray,
            anchor: bool = False) -> np.ndarray:
        """``DᵀD (S − b0) B Σ`` on the interior frames, the fixed end frames moved to the right-hand side.

        Parameters
        ----------
        frames : ndarray (f, 3m)
            Source positions (any float dtype; multiplied in row chunks, never copied whole).
        neutral : ndarray (3m,)
        first, last : ndarray (n,)
            The fixed end frames' weights.
        anchor : bool
            Regularise towards the per-frame ridge fit ``Y_pf = S B Σ (M + λ I)⁻¹`` instead of towards 0:
            ``λ ‖Y − Y_pf‖²`` adds ``λ Y_pf`` here (the operator is unchanged).

        Returns
        -------
        ndarray (f − 2, n)
        """
        F, n, sig = self.frame_count, self.n, self.sigma
        Bs = self.B * sig
        SB = np.empty((F, n))                                             # (S − b0)·B·Σ, in row chunks
        offset = neutral @ Bs
        for start in range(0, F, CHUNK_ROWS):
            rows = slice(start, min(start + CHUNK_ROWS, F))
            SB[rows] = np.asarray(frames[rows], dtype=np.float64) @ Bs - offset
        if not np.isfinite(SB).all():
            raise ShapeSpaceError("frames contain NaN or infinite values", ErrorCode.NON_FINITE)
        R = 2 * SB[1:-1] - SB[:-2] - SB[2:]
        if self.beta:                                                     # the position term β‖W Bᵀ − S‖²
            R += self.beta * SB[1:-1]
        if anchor:
            R += self.lam * ((SB[1:-1] @ self.Q) / (self.mu + self.lam)) @ self.Q.T
        # boundary frames moved to the right-hand side: DᵀD couples frame 1 to 0 and F−2 to F−1
        R[0] += (first / sig) @ self.M
        R[-1] += (last / sig) @ self.M
        return R

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """``𝓗⁻¹ rhs`` over the interior (f − 2, n), decoupled per mode: two O(f) sweeps each (pttrs)."""
        Q, mu = self.Q, self.mu
        Rq = rhs @ Q
        if self.frame_count == 3:                                   # one interior frame: a diagonal system
            return (Rq / (2.0 * mu + self.lam_modes)) @ Q.T
        Z = np.empty_like(Rq)
        for j, (diag_j, off_j) in enumerate(self.factors):
            Z[:, j] = lapack.dpttrs(diag_j, off_j, Rq[:, j])[0]
        return Z @ Q.T

    def apply(self, Y: np.ndarray) -> np.ndarray:
        """``𝓗 y = DᵀD y M + λ y`` over the interior frames (the boundary frames are fixed), (f − 2, n)."""
        T = 2.0 * Y
        T[1:] -= Y[:-1]
        T[:-1] -= Y[1:]
        if self.beta:
            T += self.beta * Y
        return T @ self.M + self.lam * Y

    def objective(self, Y: np.ndarray, R0: np.ndarray) -> float:
        """``½ yᵀ𝓗y − r₀ᵀy`` (the problem's objective up to a constant)."""
        return 0.5 * float(np.sum(Y * self.apply(Y))) - float(np.sum(R0 * Y))

    def green_tables(self, chans: np.ndarray) -> GreenTables:
        """Tables ``V1[k, k', |Δt|]`` and ``V2[k, k', t + t' + 2]`` for (at least) the channels ``chans``.

        Built once and grown to the union of the channels asked for (kept in :attr:`green`).
        """
        g = self.green
        if g is not None and np.isin(chans, g.chans).all():
            return g
        chans = np.union1d(chans, g.chans if g is not None else np.zeros(0, int))
        n, Ni, mu, lam, Q = self.n, self.frame_count - 2, self.mu, self.lam_modes, self.Q
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
        self.green = GreenTables(chans, pos, pair, (QQ @ R1).ravel(), (QQ @ R2).ravel(), R1.shape[1], R2.shape[1])
        return self.green

    def capacitance(self, active: np.ndarray) -> np.ndarray:
        """``E_Aᵀ 𝓗⁻¹ E_A``: 𝓗⁻¹ restricted to the active entries (m, m), float64, by table lookups.

        ``active`` holds flat frame-major indices ``t·n + k`` of the interior unknowns.
        """
        t, k = np.divmod(active.astype(np.int32), np.int32(self.n))
        g = self.green_tables(np.unique(k))
        kk = g.pos[k]
        pr = g.pair[kk[:, None], kk[None, :]]                                     # (m, m) channel pair
        index = pr * np.int32(g.n1)
        index += np.abs(t[:, None] - t[None, :])
        C = np.take(g.V1, index)
        np.multiply(pr, np.int32(g.n2), out=index)
        index += t[:, None] + t[None, :] + np.int32(2)
        C -= np.take(g.V2, index)
        return C                      # symmetric by construction (V1, V2 symmetric in the channel pair)

    def tables_fit(self, active: np.ndarray) -> bool:
        """Whether the Green's tables for the channels of ``active`` stay within :data:`GREEN_TABLE_LIMIT`."""
        c = np.unique(active % self.n).size
        return c * (c + 1) // 2 * 3 * (self.frame_count - 2) <= GREEN_TABLE_LIMIT

    def banded(self) -> np.ndarray:
        """``𝓗`` in LAPACK upper band storage (frame-major: (t, k) → t·n + k), bandwidth u = 2n − 1.

        Built once (kept in :attr:`band`); callers copy before modifying.
        """
        if self.band is None:
            n, M, size = self.n, self.M, self.shape[0] * self.shape[1]
            u = 2 * n - 1
            ab = np.zeros((u + 1, size))
            j = np.arange(size)
            tj, kj = np.divmod(j, n)
            for o in range(u + 1):
                i = j[o:] - o
                ti, ki = np.divmod(i, n)
                same = ti == tj[o:]
                vals = np.where(same, (2.0 + self.beta) * M[ki, kj[o:]] + self.lam * (o == 0),
                                np.where(tj[o:] == ti + 1, -M[ki, kj[o:]], 0.0))
                ab[u - o, o:] = vals
            self.band = ab
        return self.band


# ------------------------------------------------------------------ reduced Newton steps (exact, three routes)
def capacitance_step(system: SpacetimeSystem, active: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Newton step on the free entries with the active ones held, for few active entries.

    ``𝓗 d = r + E_A ν``, ``d_A = 0``, i.e. the m × m capacitance system
    ``(E_Aᵀ 𝓗⁻¹ E_A) ν = −(𝓗⁻¹ r)_A``, its matrix by closed-form lookups
    (:meth:`SpacetimeSystem.capacitance`), solved directly and refined against
    exact products (one decoupled solve each).

    Parameters
    ----------
    system : SpacetimeSystem
    active : ndarray of int (m,)
        Flat indices of the active entries.
    r : ndarray (f − 2, n)

    Returns
    -------
    ndarray (f − 2, n)
        ``d`` with ``d_A = 0`` exactly.
    """
    d = system.solve(r)
    system.solves += 1
    if not active.size:
        return d
    C = system.capacitance(active)

    def apply(v: np.ndarray) -> np.ndarray:     # numpy's LU (refinement below rarely needs a second call)
        try:
            return np.linalg.solve(C, v)
        except np.linalg.LinAlgError:
            return np.linalg.lstsq(C, v, rcond=None)[0]

    b = -d.ravel()[active]
    b_norm = float(np.linalg.norm(b))
    X = _lifted_solve(system, active, apply(b))
    for _ in range(5):                                 # iterative refinement on the exact products
        res = b - X.ravel()[active]
        if np.linalg.norm(res) <= 1e-12 * b_norm:
            break
        X += _lifted_solve(system, active, apply(res))
    d += X
    d.ravel()[active] = 0.0
    return d


def _lifted_solve(system: SpacetimeSystem, active: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``𝓗⁻¹ E_A v`` in full (f − 2, n)."""
    lift = np.zeros(system.shape[0] * system.shape[1])
    lift[active] = v
    system.solves += 1
    return system.solve(lift.reshape(system.shape))


def banded_step(system: SpacetimeSystem, free: np.ndarray, r: np.ndarray, scale: float) -> np.ndarray:
    """Newton step for large active sets: ``𝓗_FF d_F = r_F`` by a banded Cholesky.

    Frame-major, ``𝓗 = DᵀD ⊗ M + λI`` couples an entry only to entries
    ≤ 2n − 1 places away; the active entries' rows and columns are replaced by
    the identity (``d_A = 0``), which keeps the band: O(f n³).  Falls back to
    :func:`cg_step` if the factorisation fails.

    Parameters
    ----------
    system : SpacetimeSystem
    free : ndarray of bool (f − 2, n)
    r : ndarray (f − 2, n)
    scale : float
        ``max(1, ‖rhs‖∞)``, for the fallback's forcing term.

    Returns
    -------
    ndarray (f − 2, n)
    """
    ab = system.banded().copy()
    u = ab.shape[0] - 1
    keep = free.ravel()
    ab *= keep                                               # active columns
    for o in range(1, u + 1):                                # active rows i = j − o
        ab[u - o, o:] *= keep[:-o]
    ab[u, ~keep] = 1.0
    system.solves += 1
    try:
        d = solveh_banded(ab, np.where(keep, r.ravel(), 0.0), lower=False, check_finite=False)
    except np.linalg.LinAlgError:
        return cg_step(system, free, np.where(free, r, 0.0), scale, scale)
    return d.reshape(system.shape)


def cg_step(system: SpacetimeSystem, free: np.ndarray, r: np.ndarray, nat: float, scale: float,
            max_iter: int = 200) -> np.ndarray:
    """Newton step for huge problems: CG on the free entries, preconditioned by the exact unbounded inverse.

    Stops at a relative residual of ``min(0.1, √(nat / scale))`` (0: run to
    exhaustion), after ``max_iter`` iterations, or when the preconditioned
    residual vanishes.

    Parameters
    ----------
    system : SpacetimeSystem
    free : ndarray of bool (f − 2, n)
    r : ndarray (f − 2, n)
        Right-hand side, zero on the active entries.
    nat, scale : float
        Natural residual and problem scale, for the forcing term.

    Returns
    -------
    ndarray (f − 2, n)
    """
    forcing = min(0.1, np.sqrt(nat / scale))
    r_norm0 = float(np.linalg.norm(r))
    d = np.zeros_like(r)
    z = np.where(free, system.solve(r), 0.0)
    system.solves += 1
    p_dir, rz = z.copy(), float(np.sum(r * z))
    if rz == 0.0:                                          # nothing left to solve
        return d
    for _ in range(max_iter):
        Ap = np.where(free, system.apply(p_dir), 0.0)
        alpha = rz / float(np.sum(p_dir * Ap))
        d += alpha * p_dir
        r = r - alpha * Ap
        if np.linalg.norm(r) <= forcing * r_norm0:
            break
        z = np.where(free, system.solve(r), 0.0)
        system.solves += 1
        rz_new = float(np.sum(r * z))
        if rz_new == 0.0:                                  # the residual underflowed: d is exact
            break
        p_dir = z + (rz_new / rz) * p_dir
        rz = rz_new
    return d


def reduced_step(system: SpacetimeSystem, act: np.ndarray, r: np.ndarray, scale: float,
                 max_exact_active: int) -> np.ndarray:
    """Exact Newton step on the free entries (``𝓗_FF d_F = r_F``, ``d_A = 0``), by the cheapest route.

    Capacitance for ≤ ``max_exact_active`` active entries whose tables fit,
    else a banded Cholesky within :data:`BANDED_FLOP_LIMIT`, else CG.

    Parameters
    ----------
    system : SpacetimeSystem
    act : ndarray of bool (f − 2, n)
        Active entries.
    r : ndarray (f − 2, n)
    scale : float
    max_exact_active : int

    Returns
    -------
    ndarray (f − 2, n)
    """
    active = np.flatnonzero(act)
    if active.size <= max_exact_active and system.tables_fit(active):
        return capacitance_step(system, active, r)
    size, n = act.size, system.n
    if size * (2 * n) ** 2 <= BANDED_FLOP_LIMIT and size * 2 * n <= BANDED_FLOP_LIMIT / 100:
        return banded_step(system, ~act, r, scale)
    return cg_step(system, ~act, np.where(act, 0.0, r), 0.0, scale)


# ------------------------------------------------------------------ the bounded iteration
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
    for it in range(1, max_iter + 1):
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
    for it in range(1, max_iter + 1):
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


# ------------------------------------------------------------------ entry point
def _assemble(Y: np.ndarray, sig: np.ndarray, first: np.ndarray, last: np.ndarray,
              lo: np.ndarray | None = None, hi: np.ndarray | None = None) -> np.ndarray:
    """Weights (f, n) from the whitened interior ``Y`` and the fixed ends, clipped to the bounds if given."""
    W = np.empty((Y.shape[0] + 2, Y.shape[1]))
    W[0], W[-1] = first, last
    W[1:-1] = Y * sig
    if lo is not None:  # undo the rounding of the whitened bounds (lo/σ)·σ
        np.clip(W, lo, hi, out=W)
    return W


def _solve_bounded(system: SpacetimeSystem, Y: np.ndarray, R0: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                   first: np.ndarray, last: np.ndarray, tol: float, max_iter: int,
                   max_exact_active: int) -> SpacetimeResult:
    """The bounded problem from the unbounded solution ``Y``: active set, then projected Newton."""
    sig = system.sigma
    ylo = np.broadcast_to(lo / sig, Y.shape)
    yhi = np.broadcast_to(hi / sig, Y.shape)
    scale = max(1.0, float(np.abs(R0).max()))
    system.solves = 0
    Y, pdas_iterations = active_set(system, np.clip(Y, ylo, yhi), R0, ylo, yhi, max_iter, scale, max_exact_active)
    Y, newton_iterations, status, message, nat = projected_newton(
        system, np.clip(Y, ylo, yhi), R0, ylo, yhi, tol, max_iter, scale, max_exact_active)
    return SpacetimeResult(_assemble(Y, sig, first, last, lo, hi), status=status, message=message,
                           iterations=pdas_iterations + newton_iterations,
                           diagnostics={"natural_residual": nat, "solves": system.solves,
                                        "active_set_iterations": pdas_iterations,
                                        "newton_iterations": newton_iterations})


def _bound(x: ArrayLike | None, name: str, n: int, default: float) -> np.ndarray:
    """A bound as (n,) float64: ``default`` when absent, a scalar broadcast to every slider."""
    if x is None:
        return np.full(n, default)
    b = array(x, name, ndim=(0, 1), finite=False)
    if b.ndim == 1 and b.size != n:
        raise ShapeSpaceError(f"{name} must have shape ({n},), got {b.shape}", ErrorCode.SHAPE)
    if np.isnan(b).any():
        raise ShapeSpaceError(f"{name} contains NaN", ErrorCode.NON_FINITE)
    return np.broadcast_to(b, (n,))


def _sliders(indices: np.ndarray, names: Sequence[str] | None) -> str:
    """Sliders named for a message (their indices when no names are given)."""
    idx = [int(i) for i in indices]
    if names is None or len(names) <= max(idx, default=-1):
        return str(idx)
    return ", ".join(names[i] for i in idx)


def _check(B: ArrayLike, neutral: ArrayLike, frames: ArrayLike, sigma: ArrayLike, lo: ArrayLike | None,
           hi: ArrayLike | None, tol: float, max_iter: int, names: Sequence[str] | None = None) -> tuple:
    """Validated inputs of :func:`spacetime`: B, b0, S (dtype kept, not copied), σ, lo, hi."""
    B = array(B, "B", ndim=2)
    b0 = array(neutral, "neutral", shape=(B.shape[0],))
    S = np.asarray(frames)                       # not copied: only S·B is needed (memory for long shots)
    if S.ndim != 2 or S.shape[1] != B.shape[0]:
        raise ShapeSpaceError(f"frames must have shape (f, {B.shape[0]}), got {S.shape}", ErrorCode.SHAPE)
    if S.shape[0] < 3:
        raise ShapeSpaceError(f"space-time cloning needs at least 3 frames, got {S.shape[0]}", "too_short")
    n = B.shape[1]
    sig = array(sigma, "sigma", finite=False)
    if sig.size != n:
        raise ShapeSpaceError(f"sigma must have {n} entries (one per slider), got {sig.size}", ErrorCode.SHAPE)
    sig = sig.reshape(n)
    if np.any(sig <= 0) or not np.isfinite(sig).all():
        raise ShapeSpaceError(f"sigma must be positive and finite for every slider (not for "
                              f"{_sliders(np.flatnonzero(~(sig > 0) | ~np.isfinite(sig)), names)})", "range")
    lo, hi = _bound(lo, "lo", n, -np.inf), _bound(hi, "hi", n, np.inf)
    if np.any(lo > hi):
        raise ShapeSpaceError(f"lo exceeds hi for sliders {_sliders(np.flatnonzero(lo > hi), names)}",
                              ErrorCode.INFEASIBLE)
    positive(tol, "tol")
    if int(max_iter) < 1:
        raise ShapeSpaceError(f"max_iter must be at least 1, got {max_iter}", ErrorCode.RANGE)
    return B, b0, S, sig, lo, hi


def spacetime(B: ArrayLike, neutral: ArrayLike, frames: ArrayLike, sigma: ArrayLike, lam: float = 1e-3,
              first: ArrayLike | None = None, last: ArrayLike | None = None, lo: ArrayLike | None = None,
              hi: ArrayLike | None = None, tol: float = 1e-8, max_iter: int = 100, relative: bool = False,
              max_exact_active: int = 1000, names: Sequence[str] | None = None,
              beta: float = 0.0, anchor: bool = False) -> SpacetimeResult:
    """Space-time expression cloning (thesis ch. 5), optionally with slider bounds.

    Minimises ``‖D (W Bᵀ − S)‖² + β ‖W Bᵀ − S‖² + λ Σ_f Σ_k (w_fk / σ_k)²`` over the interior
    frames, with ``W[0] = first`` and ``W[-1] = last`` fixed (default: the
    per-frame fits of the end frames, :func:`~.perframe.fit_frames`), where
    ``S`` are the source positions at the corresponding points relative to the
    target neutral and ``D`` the temporal first difference; with ``lo``/``hi``
    subject to ``lo ≤ w ≤ hi``.  See the module docstring for the method.

    Parameters
    ----------
    B : ndarray (3m, n)
        Target delta-matrix rows at the corresponding points.
    neutral : ndarray (3m,)
    frames : ndarray (f, 3m)
        Source positions, f ≥ 3 (float32 is fine: multiplied in row chunks).
    sigma : ndarray (n,)
        Per-slider scale σ_k (e.g. standard deviations of training weights, 5.5).
    lam : float
        λ.
    first, last : ndarray (n,), optional
        Fixed end frames.
    lo, hi : ndarray (n,) or float, optional
        Slider bounds (either may be omitted or infinite); giving either makes the problem bounded.
    tol : float
        Natural-residual tolerance of the bounded solve, relative to ``max(1, ‖rhs‖∞)``.
    max_iter : int
        Iteration limit of each of the two bounded phases.
    relative : bool
        Read ``lam`` relative to the data: λ · mean eigenvalue of ``ΣBᵀBΣ``
        (unit-free; used by the retarget command).
    max_exact_active : int
        Largest active set for which a Newton step uses the capacitance
        system (cost O(m³) plus lookup tables of O(c²·f) for the c channels
        involved); larger ones use the banded Cholesky (or CG).
    names : sequence of str (n,), optional
        Slider names for the messages (indices otherwise).
    beta : float
        β ≥ 0, weight of the position term (per frame², relative to the
        velocity term).  0 is the thesis' pure velocity matching; a small β
        (e.g. :data:`DRIFT_BETA`) anchors long takes so that errors the
        regulariser lets into slow modes cannot integrate into drift, while
        clipped stretches shorter than about 1/√β frames keep their velocity
        shape (Fig. 3.9).  Each mode stays one tridiagonal system
        ``(μ_j (T + β I) + λ) z_j = r_j``.
    anchor : bool
        Regularise towards the per-frame ridge fit instead of towards zero:
        ``λ Σ_f Σ_k ((w_fk − w⁰_fk) / σ_k)²`` with ``W⁰ = argmin ‖W Bᵀ − S‖² + λ ‖W Σ⁻¹‖²``
        frame by frame.  Where nothing clips, ``W⁰`` (plus the velocity
        term's own minimiser, the same up to O(λ)) is the answer: no drift on
        long takes, which the zero-pulling regulariser causes in modes with
        ``μ_j ≲ λ f²``.  Where sliders clip the pull is as weak as before, so
        the velocity shape is kept (Fig. 3.9).  Used by the retarget command.

    Returns
    -------
    SpacetimeResult
        ``weights`` (f, n), within the bounds exactly; ``status`` ``OK`` or
        ``NOT_CONVERGED`` (iteration limit, stalled).
    """
    bounded = lo is not None or hi is not None
    B, b0, S, sig, lo, hi = _check(B, neutral, frames, sigma, lo, hi, tol, max_iter, names)
    lam = finite_scalar(lam, "lam")
    beta = finite_scalar(beta, "beta")
    if beta < 0:
        raise ShapeSpaceError(f"beta must be ≥ 0, got {beta}", "range")
    F, n = S.shape[0], B.shape[1]
    if first is None or last is None:
        ends = fit_frames(B, b0, S[[0, -1]].astype(np.float64), lo if bounded else np.full(n, -1e6),
                          hi if bounded else np.full(n, 1e6))
        first = ends[0] if first is None else first
        last = ends[1] if last is None else last
    first, last = array(first, "first", shape=(n,)), array(last, "last", shape=(n,))
    system = SpacetimeSystem(B, sig, lam, F, relative, beta)
    R0 = system.rhs(S, b0, first, last, anchor)
    Y = system.solve(R0)
    if not bounded:
        return SpacetimeResult(_assemble(Y, sig, first, last), diagnostics={"modes": n})
    return _solve_bounded(system, Y, R0, lo, hi, first, last, tol, max_iter, max_exact_active)
