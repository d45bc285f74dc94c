"""The space-time system: the whitened problem, its per-mode factors and the operator ``𝓗`` (thesis ch. 5).

:class:`SpacetimeSystem` holds ``M = Σ BᵀB Σ`` and its eigendecomposition, the per-mode tridiagonal factors of
``μ_j T + λ I`` (the unbounded solve), applies ``𝓗 = DᵀD ⊗ M + λ I`` and gives its band; :class:`GreenTables`
the entries of ``𝓗⁻¹`` the capacitance route looks up.  The problem is stated in the package docstring
(:mod:`core.retarget.spacetime_solver`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import lapack

from ...errors import ErrorCode
from ...progress import ProgressFn, notify
from ...result import ShapeSpaceError

__all__ = ["SpacetimeSystem", "GreenTables", "GREEN_TABLE_LIMIT", "CHUNK_ROWS"]

#: Largest Green's-function lookup tables (entries, 8 bytes each: ≤ 320 MB) the capacitance route may build.
GREEN_TABLE_LIMIT = 4e7

#: Source rows multiplied at a time when forming ``S B Σ`` (the source is never copied as a whole).
CHUNK_ROWS = 2048


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
            anchor: bool = False, *, progress: ProgressFn | None = None) -> np.ndarray:
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
        progress : callable, optional
            Called after each chunk of :data:`CHUNK_ROWS` source rows.

        Returns
        -------
        ndarray (f − 2, n)
        """
        F, n, sig = self.frame_count, self.n, self.sigma
        Bs = self.B * sig
        SB = np.empty((F, n))                                             # (S − b0)·B·Σ, in row chunks
        offset = neutral @ Bs
        for start in range(0, F, CHUNK_ROWS):
            notify(progress, start / F)
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
