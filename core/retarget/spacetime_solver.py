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

Bounds.  The bounded problem ``min ½ yᵀ𝓗y − r₀ᵀy, lo/σ ≤ y ≤ hi/σ`` is
solved exactly: every step is an exact solve of ``𝓗_FF d_F = r_F`` with the
held (active) entries fixed, by a block-tridiagonal Cholesky of ``𝓗`` in
frame-major order (:class:`BlockCholesky`: blocks ``(2 + β) M + λ I`` and
``−M``, held rows/columns replaced by the identity; O(f n³) flops in BLAS-3
blocks, memory f·n², linear in the take length).  The held set is found by

- :func:`peak_active_set` (first): from the unbounded solution, hold the
  deepest entry of every run of violated frames of a slider and release held
  entries whose multiplier has the wrong sign.  Holding all violated entries
  (the clipped unbounded solution) overshoots: on real takes most of them end
  up free, lifted by the velocity coupling (facecap→FBHead: 7,231 violated,
  1,059 active; the 1,640-frame take: 12,997 and 2,612), and a primal–dual
  active-set method then needs 23–88 iterations to shed them; holding run
  peaks needs 8–14;
- :func:`interior_point` (Mehrotra predictor–corrector, one block factor per
  iteration) when the rig is rank-deficient (duplicate keys: ``M`` singular,
  bounded ties that only λ tells apart, on which active-set iterations cycle)
  or the peak iteration stops progressing; it finishes with an exact solve on
  the barrier's active set (:func:`_crossover`).

The earlier routes stay as fallbacks: the primal–dual active set
(Hintermüller–Ito–Kunisch, :func:`active_set`) whose steps
(:func:`reduced_step`) use the m × m capacitance system
``(E_Aᵀ 𝓗⁻¹ E_A) ν = −(𝓗⁻¹ r)_A`` from closed-form per-mode Green's functions
of ``T`` (:class:`GreenTables`, :func:`capacitance_step`) for few active
entries, else the block Cholesky, else conjugate gradients preconditioned by
the unbounded inverse (:func:`cg_step`); and a projected Newton method with
an ε-active set and a projected Armijo search (Bertsekas 1982; monotone,
:func:`projected_newton`), which also checks the final point.  Convergence
test: the natural residual ``‖y − clip(y − ∇f(y))‖∞ ≤ tol · max(1, ‖rhs‖∞)``
in the whitened variables (zero exactly at the KKT point), or no further
decrease at a residual ≤ 1e-6 (rounding).  The returned weights satisfy the
bounds exactly.

Ties.  On a rig with duplicate or dependent keys the geometric terms do not
decide between the keys; the regulariser does: towards zero (``λ Σ (w/σ)²``,
the smallest σ-weighted norm) or, with ``anchor``, towards the per-frame ridge
fit (the smallest σ-weighted-norm split).  Among exact
duplicates the motion is shared in proportion to ``σ_k²``: with the retarget
command's σ (each slider's spread in the source, floored), a key the source
drives takes the motion and a vendor duplicate no channel drives stays near
zero; duplicates with equal σ share equally.  The default end frames use the
same weighting (:func:`_end_frames`), so a split does not jump at frame 1.
The retarget command leaves keys that move nothing out of the fit.

Progress.  :func:`spacetime` takes ``progress`` (:mod:`core.progress`):
called per chunk of source rows and per bounded iteration; a
:class:`~core.progress.Cancelled` raised from it ends the solve.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.linalg import blas, lapack, solveh_banded

from ..blas_threads import single_threaded
from ..errors import ErrorCode
from ..progress import ProgressFn, notify, scaled
from ..result import Result, ShapeSpaceError, Status
from ..validate import array, finite_scalar, positive
from .perframe import fit_frames

__all__ = ["spacetime", "DRIFT_BETA", "SpacetimeResult", "SpacetimeSystem", "GreenTables", "BANDED_FLOP_LIMIT",
           "reduced_step", "capacitance_step", "banded_step", "cg_step", "active_set", "projected_newton",
           "BlockCholesky", "BLOCK_BYTES_LIMIT", "block_step", "capacitance_limit", "run_peaks", "peak_active_set",
           "interior_point"]

#: Largest banded-Cholesky Newton step (≈ flops, f·n·(2n)²) before bounded space-time falls back to CG.
BANDED_FLOP_LIMIT = 4e9

#: Largest Green's-function lookup tables (entries, 8 bytes each: ≤ 320 MB) the capacitance route may build.
GREEN_TABLE_LIMIT = 4e7

#: Source rows multiplied at a time when forming ``S B Σ`` (the source is never copied as a whole).
CHUNK_ROWS = 2048

#: Default β of the retarget command's space-time method (position term, per frame²; #11).
DRIFT_BETA = 1e-3

#: Ridge of the default end frames' per-frame fits in the whitened variables w/σ (relative to tr(ΣBᵀBΣ)/n, as
#: the retarget command's λ): small enough that the ends are the least-squares fits to ~1e-7 of the weights on a
#: rig without ties, large enough to split ties (by σ²) to float precision.
END_RIDGE = 1e-7

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


# ------------------------------------------------------------------ block-tridiagonal Cholesky (the exact route)
class BlockCholesky:
    """Cholesky factor of ``𝓗 + diag(δ)`` with the ``held`` entries' rows and columns replaced by the identity.

    Frame-major, ``𝓗`` is block tridiagonal: diagonal blocks ``(2 + β) M + λ I``,
    off-diagonal blocks ``B_t = −M``.  The factor has blocks ``L_t`` (lower
    triangular, n × n) on the diagonal and ``C_t = B_t L_{t−1}^{−T}`` below,
    from ``S_t = A_t − C_t C_tᵀ = L_t L_tᵀ`` frame after frame: O(f n³) flops
    in BLAS-3 blocks and memory f·n² (the ``L_t``; also ``X_t = C_tᵀ`` up to
    :data:`BLOCK_KEEP_BYTES`, else recomputed), linear in the take length; a
    solve is two sweeps of triangular solves and products, one frame at a time.

    Parameters
    ----------
    system : SpacetimeSystem
    held : ndarray of bool (f − 2, n), optional
        Entries held fixed (their step is 0).
    shift : ndarray (f − 2, n), optional
        Diagonal ``δ`` added to ``𝓗`` (≥ 0; the interior-point barrier).
    previous : BlockCholesky, optional
        A factor of the same system with another held set (no shift): its blocks before the first frame
        whose held entries differ are taken over (and it can no longer be used).
    progress : callable, optional
        Called every :data:`PROGRESS_BLOCKS` frames of the factorisation (:mod:`core.progress`; a long take's
        factor takes seconds, and a cancel is honoured there).

    Raises
    ------
    numpy.linalg.LinAlgError
        If a block is not numerically positive definite.
    """

    def __init__(self, system: SpacetimeSystem, held: np.ndarray | None = None, shift: np.ndarray | None = None,
                 previous: BlockCholesky | None = None, progress: ProgressFn | None = None):
        N, n = system.shape
        self.shape = (N, n)
        M = system.M
        A = (2.0 + system.beta) * M
        A[np.diag_indices(n)] += system.lam
        self.M = M
        self.keep = None if held is None or not held.any() else ~held
        self.touched = touched = np.zeros(N, dtype=bool) if self.keep is None else held.any(axis=1)
        self.held = np.zeros((N, n), dtype=bool) if held is None else held.copy()
        self.shifted = shift is not None
        start = 0
        if previous is not None and not self.shifted and not previous.shifted and previous.shape == self.shape:
            # the factor is a forward recursion: frames before the first change keep their blocks
            changed = np.flatnonzero((previous.held != self.held).any(axis=1))
            start = int(changed[0]) if changed.size else N
            self.L, self.X = previous.L, previous.X                  # taken over (the previous factor is spent)
            previous.L = previous.X = None
        else:
            self.L = np.empty((N, n, n))
            self.X = np.empty((N, n, n)) if N * n * n * 8 <= BLOCK_KEEP_BYTES else None   # else recomputed
        diag = np.diag_indices(n)
        keep = self.keep
        for t in range(start, N):
            if progress is not None and t % PROGRESS_BLOCKS == 0:
                notify(progress, t / N)
            if touched[t] or shift is not None:
                At = A.copy()
                if shift is not None:
                    At[diag] += shift[t]
                if touched[t]:
                    k = keep[t]
                    At *= k[:, None]
                    At *= k[None, :]
                    At[diag] += ~k
            else:
                At = A
            if t:
                Bt = -M if not (touched[t] or touched[t - 1]) else -(M * keep[t - 1][:, None]) * keep[t][None, :]
                X = lapack.dtrtrs(self.L[t - 1], Bt, lower=1)[0]             # L_{t−1}⁻¹ B_tᵀ = C_tᵀ (M symmetric)
                if self.X is not None:
                    self.X[t] = X
                At = blas.dsyrk(-1.0, X, 1.0, At, trans=1, lower=1)                 # A_t − XᵀX (lower half)
            elif At is A:
                At = A.copy()
            Lt, info = lapack.dpotrf(At, lower=1, clean=1, overwrite_a=1)
            if info:
                raise np.linalg.LinAlgError(f"block {t} is not positive definite")
            self.L[t] = Lt

    def _b(self, t: int, v: np.ndarray, transpose: bool) -> np.ndarray:
        """``B_t v`` (``B_tᵀ v`` with ``transpose``) without forming ``B_t`` (rows of frame t, columns of t − 1)."""
        if self.keep is None or not (self.touched[t] or self.touched[t - 1]):
            return -(self.M @ v)
        rows, cols = (self.keep[t - 1], self.keep[t]) if transpose else (self.keep[t], self.keep[t - 1])
        return -(rows * (self.M @ (cols * v)))

    def solve(self, r: np.ndarray) -> np.ndarray:
        """The solution (f − 2, n) of the held system for the right-hand side ``r`` (held entries get 0)."""
        N = self.shape[0]
        L, X = self.L, self.X
        u = np.array(r if self.keep is None else np.where(self.keep, r, 0.0), dtype=np.float64)
        u[0] = lapack.dtrtrs(L[0], u[0], lower=1)[0]
        for t in range(1, N):                                   # C_t u = X_tᵀ u = B_t L_{t−1}⁻ᵀ u
            cu = (u[t - 1] @ X[t] if X is not None
                  else self._b(t, lapack.dtrtrs(L[t - 1], u[t - 1], lower=1, trans=1)[0], False))
            u[t] = lapack.dtrtrs(L[t], u[t] - cu, lower=1)[0]
        u[N - 1] = lapack.dtrtrs(L[N - 1], u[N - 1], lower=1, trans=1)[0]
        for t in range(N - 2, -1, -1):                          # C_{t+1}ᵀ d = X_{t+1} d = L_t⁻¹ B_{t+1}ᵀ d
            cd = (X[t + 1] @ u[t + 1] if X is not None
                  else lapack.dtrtrs(L[t], self._b(t + 1, u[t + 1], True), lower=1)[0])
            u[t] = lapack.dtrtrs(L[t], u[t] - cd, lower=1, trans=1)[0]
        if self.keep is not None:
            u[~self.keep] = 0.0
        return u


#: A rig whose ``M`` has an eigenvalue at most this fraction of its largest is rank-deficient: bounded space-time
#: goes straight to the interior point.
DEGENERATE_RATIO = 1e-10

#: Iterations :func:`peak_active_set` may go without lowering the best 2-norm of its natural residual by 10 %.
PEAK_PATIENCE = 5

#: Largest block-Cholesky factor (bytes: (f − 2) · n² · 8) the exact route builds; beyond it CG is used.
BLOCK_BYTES_LIMIT = 2 * 2 ** 30

#: Frames factored between two progress calls of :class:`BlockCholesky` (when given one).
PROGRESS_BLOCKS = 4096

#: :func:`clipped_solve` is tried first when no entry of the unbounded solution violates its bound by more than
#: this fraction of the slider's range (tiny dips below 0 where the source rests; never real clipping).
SHALLOW_VIOLATION = 1e-3

#: Up to this size (bytes, (f − 2) · n² · 8) :class:`BlockCholesky` also keeps the ``C_t`` (faster solves);
#: beyond it they are recomputed by triangular solves, so the memory stays one factor.
BLOCK_KEEP_BYTES = 2 ** 28


def block_step(system: SpacetimeSystem, act: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Exact Newton step ``𝓗_FF d_F = r_F``, ``d_A = 0`` by the block-tridiagonal Cholesky (:class:`BlockCholesky`).

    Parameters
    ----------
    system : SpacetimeSystem
    act : ndarray of bool (f − 2, n)
    r : ndarray (f − 2, n)

    Returns
    -------
    ndarray (f − 2, n)
    """
    system.solves += 1
    return BlockCholesky(system, act).solve(r)


def capacitance_limit(system: SpacetimeSystem) -> int:
    """Largest held set for which the capacitance route is cheaper than a block factorisation (cost model).

    Capacitance: ``m³/3`` flops for its Cholesky plus ~2 table lookups per entry (``m²``); block Cholesky:
    ``7/3 · n³`` flops per frame plus a fixed per-frame overhead (a dozen LAPACK calls from Python, ~10⁵ flops'
    worth).
    """
    block = system.shape[0] * (7.0 / 3.0 * system.n ** 3 + 1e5)
    m = np.arange(1, 20001, 16, dtype=np.float64)
    cheaper = m ** 3 / 3.0 + 40.0 * m * m <= block
    return int(m[cheaper].max()) if cheaper.any() else 0


def _block_fits(system: SpacetimeSystem) -> bool:
    """Whether :class:`BlockCholesky` stays within :data:`BLOCK_BYTES_LIMIT`."""
    return system.shape[0] * system.n * system.n * 8 <= BLOCK_BYTES_LIMIT


def run_peaks(v: np.ndarray) -> np.ndarray:
    """The deepest entry of every run of consecutive positive entries along time, per channel.

    Parameters
    ----------
    v : ndarray (f − 2, n)
        Violation (> 0 where violated).

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
        out[idx[vals[idx] >= peak[run]]] = True
    return out.reshape(n, N + 1)[:, :N].T


def reduced_step(system: SpacetimeSystem, act: np.ndarray, r: np.ndarray, scale: float,
                 max_exact_active: int) -> np.ndarray:
    """Exact Newton step on the free entries (``𝓗_FF d_F = r_F``, ``d_A = 0``), by the cheapest route.

    Capacitance for ≤ ``max_exact_active`` active entries whose tables fit,
    else the block-tridiagonal Cholesky within :data:`BLOCK_BYTES_LIMIT`, else CG.

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
    if _block_fits(system):
        try:
            return block_step(system, act, r)
        except np.linalg.LinAlgError:
            pass
    return cg_step(system, ~act, np.where(act, 0.0, r), 0.0, scale)


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
        Whether the natural residual meets ``tol · scale`` (else the caller starts over from ``Y``).
    """
    upper, lower = Y > yhi, Y < ylo
    Yh = np.where(upper, yhi, np.where(lower, ylo, Y))
    try:
        factor = BlockCholesky(system, upper | lower, progress=progress)
    except np.linalg.LinAlgError:
        return Y, False
    system.solves += 1
    Yn = Yh + factor.solve(R0 - system.apply(Yh))
    return Yn, _natural(Yn, R0 - system.apply(Yn), ylo, yhi) <= tol * scale


def peak_active_set(system: SpacetimeSystem, Y: np.ndarray, R0: np.ndarray, ylo: np.ndarray, yhi: np.ndarray,
                    tol: float, max_iter: int, scale: float, progress: ProgressFn | None = None) -> tuple:
    """Active set grown from below: hold the deepest entry of every violated run, free wrong-signed holds.

    From the unbounded solution, each iteration holds (at its bound) the most
    violated entry of every run of consecutive violated frames of a slider,
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
        The unbounded solution.
    R0, ylo, yhi : ndarray (f − 2, n)
    tol, scale : float
    max_iter : int
    progress : callable, optional
        Called with the iteration's fraction of ``max_iter``.

    Returns
    -------
    Y : ndarray (f − 2, n)
        The last iterate (exact for its held set; may violate the bounds when not converged).
    iterations : int
    converged : bool
    """
    lower = np.zeros(Y.shape, dtype=bool)
    upper = np.zeros(Y.shape, dtype=bool)
    seen = set()
    best, since = np.inf, 0
    limit, factor = capacitance_limit(system), None
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
        add_lo = run_peaks(np.where(held, 0.0, ylo - Y - thr))
        add_hi = run_peaks(np.where(held, 0.0, Y - yhi - thr))
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
                   max_exact_active: int, progress: ProgressFn | None = None) -> SpacetimeResult:
    """The bounded problem from the unbounded solution ``Y``.

    :func:`peak_active_set` first (a handful of exact block solves on real
    takes); if it cycles, or the rig is rank-deficient (smallest eigenvalue of
    ``M`` ≤ :data:`DEGENERATE_RATIO` × the largest), :func:`interior_point`
    (robust on degenerate, redundant rigs); if that fails too, the primal–dual active set and
    projected Newton of before.  The final :func:`projected_newton` call
    checks the natural residual of the point returned (and returns at once
    when it passes).
    """
    sig = system.sigma
    ylo = np.broadcast_to(lo / sig, Y.shape)
    yhi = np.broadcast_to(hi / sig, Y.shape)
    scale = max(1.0, float(np.abs(R0).max()))
    system.solves = 0
    peak_iterations = ipm_iterations = pdas_iterations = 0
    exact = _block_fits(system)
    Ys, done = Y, False
    # a rank-deficient rig (duplicate keys: M singular) has many bounded ties only λ tells apart, on which active-set
    # iterations cycle; the interior point goes straight through them
    degenerate = float(system.mu.min()) <= DEGENERATE_RATIO * float(system.mu.max())
    clipped = exact and shallow_violation(Y, ylo, yhi)
    if clipped:                              # nothing really clips: hold every sliver, one solve (usually final)
        Ys, done = clipped_solve(system, Y, R0, ylo, yhi, tol, scale, scaled(progress, 0.0, 0.5))
        Ys = Ys if done else Y
    if exact and not degenerate and not done:
        Ys, peak_iterations, done = peak_active_set(system, Y, R0, ylo, yhi, tol, max_iter, scale,
                                                    scaled(progress, 0.0, 0.5))
    if not done and exact and bool(np.all(lo < hi)):
        Ys, ipm_iterations, done = interior_point(system, Y, R0, ylo, yhi, tol, max_iter, scale,
                                                  scaled(progress, 0.5, 0.9))
        done = True                          # projected Newton finishes from the interior point's answer
    if not done:
        Ys, pdas_iterations = active_set(system, np.clip(Y, ylo, yhi), R0, ylo, yhi, max_iter, scale,
                                         max_exact_active)
    notify(progress, 0.9)
    Ys, newton_iterations, status, message, nat = projected_newton(
        system, np.clip(Ys, ylo, yhi), R0, ylo, yhi, tol, max_iter, scale, max_exact_active)
    notify(progress, 1.0)
    return SpacetimeResult(_assemble(Ys, sig, first, last, lo, hi), status=status, message=message,
                           iterations=peak_iterations + ipm_iterations + pdas_iterations + newton_iterations,
                           diagnostics={"natural_residual": nat, "solves": system.solves,
                                        "clipped_solve": bool(clipped),
                                        "peak_iterations": peak_iterations,
                                        "interior_point_iterations": ipm_iterations,
                                        "active_set_iterations": pdas_iterations,
                                        "newton_iterations": newton_iterations})


def _end_frames(B: np.ndarray, b0: np.ndarray, S: np.ndarray, sig: np.ndarray, lo: np.ndarray,
                hi: np.ndarray) -> np.ndarray:
    """The default fixed end frames (2, n): the per-frame bounded fits of the first and last source frames
    (:func:`~.perframe.fit_frames`, ridge :data:`END_RIDGE`) in the interior's whitened variables ``w / σ``, so a tie
    between duplicate keys splits in proportion to ``σ²`` at the ends as in between (no jump at frame 1);
    on a rig without ties the ridge is negligible either way."""
    W = fit_frames(B * sig, b0, S[[0, -1]].astype(np.float64), lo / sig, hi / sig, reg=END_RIDGE) * sig
    return np.clip(W, lo, hi)              # (lo/σ)·σ can round past lo


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
              beta: float = 0.0, anchor: bool = False, *, progress: ProgressFn | None = None) -> SpacetimeResult:
    """Space-time expression cloning (thesis ch. 5), optionally with slider bounds.

    Minimises ``‖D (W Bᵀ − S)‖² + β ‖W Bᵀ − S‖² + λ Σ_f Σ_k (w_fk / σ_k)²`` over the interior
    frames, with ``W[0] = first`` and ``W[-1] = last`` fixed (default: the
    per-frame fits of the end frames in the variables ``w / σ``, :func:`_end_frames`), where
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
    progress : callable, optional
        ``progress(fraction)`` while the source is multiplied (per chunk of
        :data:`CHUNK_ROWS` frames) and after every bounded iteration
        (:mod:`core.progress`); raising :class:`~core.progress.Cancelled` from
        it stops the solve.

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
        ends = _end_frames(B, b0, S, sig, lo if bounded else np.full(n, -1e6), hi if bounded else np.full(n, 1e6))
        first = ends[0] if first is None else first
        last = ends[1] if last is None else last
    first, last = array(first, "first", shape=(n,)), array(last, "last", shape=(n,))
    system = SpacetimeSystem(B, sig, lam, F, relative, beta)
    R0 = system.rhs(S, b0, first, last, anchor, progress=scaled(progress, 0.0, 0.3 if bounded else 0.95))
    Y = system.solve(R0)
    if not bounded:
        notify(progress, 1.0)
        return SpacetimeResult(_assemble(Y, sig, first, last), diagnostics={"modes": n})
    with single_threaded():                  # thousands of small BLAS calls: threads only spin (core.blas_threads)
        return _solve_bounded(system, Y, R0, lo, hi, first, last, tol, max_iter, max_exact_active,
                              scaled(progress, 0.3, 1.0))
