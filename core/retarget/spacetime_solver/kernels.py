"""The kernels: exact reduced Newton steps ``𝓗_FF d_F = r_F`` with the held entries fixed (``d_A = 0``).

- :func:`capacitance_step` — few held entries: the m × m capacitance system from :class:`.system.GreenTables`;
- :func:`banded_step` — the banded Cholesky of ``𝓗_FF``;
- :func:`cg_step` — conjugate gradients preconditioned by the unbounded inverse (huge problems);
- :class:`BlockCholesky` / :func:`block_step` — the block-tridiagonal Cholesky in frame-major order (the exact
  route, O(f n³), memory f·n²);

and :func:`reduced_step`, which picks the cheapest of them.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import blas, lapack, solveh_banded

from ...progress import ProgressFn, notify
from .system import SpacetimeSystem

__all__ = ["reduced_step", "capacitance_step", "banded_step", "cg_step", "BlockCholesky", "block_step",
           "capacitance_limit", "block_fits", "BANDED_FLOP_LIMIT", "BLOCK_BYTES_LIMIT", "PROGRESS_BLOCKS",
           "BLOCK_KEEP_BYTES"]

#: Largest banded-Cholesky Newton step (≈ flops, f·n·(2n)²) before bounded space-time falls back to CG.
BANDED_FLOP_LIMIT = 4e9

#: Largest block-Cholesky factor (bytes: (f − 2) · n² · 8) the exact route builds; beyond it CG is used.
BLOCK_BYTES_LIMIT = 2 * 2 ** 30

#: Frames factored between two progress calls of :class:`BlockCholesky` (when given one).
PROGRESS_BLOCKS = 4096

#: Up to this size (bytes, (f − 2) · n² · 8) :class:`BlockCholesky` also keeps the ``C_t`` (faster solves);
#: beyond it they are recomputed by triangular solves, so the memory stays one factor.
BLOCK_KEEP_BYTES = 2 ** 28


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


def block_fits(system: SpacetimeSystem) -> bool:
    """Whether :class:`BlockCholesky` stays within :data:`BLOCK_BYTES_LIMIT`."""
    return system.shape[0] * system.n * system.n * 8 <= BLOCK_BYTES_LIMIT


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
    if block_fits(system):
        try:
            return block_step(system, act, r)
        except np.linalg.LinAlgError:
            pass
    return cg_step(system, ~act, np.where(act, 0.0, r), 0.0, scale)
