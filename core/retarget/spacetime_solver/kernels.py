"""The kernels: exact reduced Newton steps ``𝓗_FF d_F = r_F`` with the held entries fixed (``d_A = 0``).

- :func:`capacitance_step` — few held entries: the m × m capacitance system from :class:`.system.GreenTables`;
- :func:`banded_step` — the banded Cholesky of ``𝓗_FF``;
- :func:`cg_step` — conjugate gradients preconditioned by the unbounded inverse (huge problems);
- :class:`BlockCholesky` / :func:`block_step` — the block-tridiagonal Cholesky in frame-major order (the exact
  route on each frame's free entries, O(Σ |F_t|³), memory Σ |F_t|² / 2);

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

#: Largest block-Cholesky factor (bytes: (f − 2) · n (n + 1) / 2 · 8, packed, nothing held) the exact route builds;
#: beyond it CG is used.
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
    """Cholesky factor of ``𝓗 + diag(δ)`` restricted to the entries not ``held`` (their step is 0).

    Frame-major, ``𝓗`` is block tridiagonal: diagonal blocks ``(2 + β) M + λ I``,
    off-diagonal blocks ``B_t = −M``.  On the free entries F_t of each frame the blocks are
    ``A_t = ((2 + β) M + λ I)[F_t, F_t]`` and ``B_t = −M[F_t, F_{t−1}]``, and the factor has blocks ``L_t``
    (lower triangular, |F_t| × |F_t|) on the diagonal and ``C_t = B_t L_{t−1}^{−T}`` below, from
    ``S_t = A_t − C_t C_tᵀ = L_t L_tᵀ`` frame after frame: O(Σ |F_t|³) flops in BLAS-3 blocks and memory
    Σ |F_t|² / 2 (the ``L_t``, packed one after another; also ``X_t = C_tᵀ`` up to :data:`BLOCK_KEEP_BYTES`,
    else recomputed), linear in the take length.  A held entry costs nothing: on a 10-minute take solved onto
    ICT FaceKit, where 17 % of the entries rest on a bound, the packed factor is 0.35 of the memory of whole
    frames and about half their flops.  A solve is two sweeps of triangular solves and products, one frame at a time.

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
        self.M = system.M
        self.held = np.zeros((N, n), dtype=bool) if held is None else held.copy()
        self.shifted = shift is not None
        self.cols, self.size = _free_columns(self.held)
        size = np.array(self.size, dtype=np.int64)
        self.at = np.r_[0, np.cumsum(size * (size + 1) // 2)].tolist()   # where each packed L_t starts
        keep_x = N * n * n * 8 <= BLOCK_KEEP_BYTES
        self.x_at = np.r_[0, 0, np.cumsum(size[:-1] * size[1:])].tolist() if keep_x else None
        start = 0
        if previous is not None and not self.shifted and not previous.shifted and previous.shape == self.shape:
            # the factor is a forward recursion: frames before the first change keep their blocks (and places)
            changed = np.flatnonzero((previous.held != self.held).any(axis=1))
            start = int(changed[0]) if changed.size else N
            self.L, self.X = previous.L, previous.X                  # taken over (the previous factor is spent)
            previous.L = previous.X = None
        else:                                                         # room for whole frames; pages touched as written
            self.L = np.empty(N * n * (n + 1) // 2)
            self.X = np.empty(N * n * n) if keep_x else None
        A = (2.0 + system.beta) * system.M
        A[np.diag_indices(n)] += system.lam
        run = _Gathers(A, -system.M)
        last = None if start == 0 or self.size[start - 1] == 0 else self._unpacked(start - 1)
        for t in range(start, N):
            if progress is not None and t % PROGRESS_BLOCKS == 0:
                notify(progress, t / N)
            last = self._factor(t, run, last, None if shift is None else shift[t])

    def _factor(self, t: int, run: _Gathers, last: np.ndarray | None, shift: np.ndarray | None) -> np.ndarray | None:
        """``L_t`` (and ``X_t``) from ``last`` = ``L_{t−1}`` (None when frame t − 1 has nothing free):
        ``S_t = A_t − X_tᵀ X_t``, ``X_t = L_{t−1}⁻¹ B_tᵀ``; stored packed, returned whole (None: nothing free)."""
        k, c = self.size[t], self.cols[t]
        if k == 0:
            return None
        At = run.diagonal(c).copy()
        if shift is not None:
            At[np.diag_indices(k)] += shift if c is None else shift[c]
        if last is not None:
            X = lapack.dtrtrs(last, run.coupling(self.cols[t - 1], c), lower=1)[0]   # L_{t−1}⁻¹ B_tᵀ = C_tᵀ
            if self.x_at is not None:
                self.X[self.x_at[t]:self.x_at[t + 1]] = X.ravel(order="F")
            At = blas.dsyrk(-1.0, X, 1.0, At, trans=1, lower=1)         # A_t − XᵀX (lower half)
        Lt, info = lapack.dpotrf(At, lower=1, clean=1, overwrite_a=1)
        if info:
            raise np.linalg.LinAlgError(f"block {t} is not positive definite")
        self.L[self.at[t]:self.at[t + 1]] = lapack.dtrttp(Lt, uplo="L")[0]
        return Lt

    def _unpacked(self, t: int) -> np.ndarray:
        """``L_t`` (|F_t|, |F_t|) whole (lower triangle, zeros above)."""
        return lapack.dtpttr(self.size[t], self.L[self.at[t]:self.at[t + 1]], uplo="L")[0]

    def _tri(self, t: int, v: np.ndarray, transpose: bool) -> np.ndarray:
        """``L_t⁻¹ v`` (``L_t⁻ᵀ v`` with ``transpose``) on the packed ``L_t``."""
        return blas.dtpsv(self.size[t], self.L[self.at[t]:self.at[t + 1]], v, lower=1, trans=int(transpose))

    def _x(self, t: int) -> np.ndarray:
        """``X_t = C_tᵀ`` (|F_{t−1}|, |F_t|), a view."""
        return self.X[self.x_at[t]:self.x_at[t + 1]].reshape(self.size[t - 1], self.size[t], order="F")

    def _couple(self, s: int, t: int, v: np.ndarray) -> np.ndarray:
        """``−M[F_s, F_t] v`` without forming the block (``v`` on the free entries of frame t)."""
        a, b = self.cols[s], self.cols[t]
        if b is not None:
            w = np.zeros(self.shape[1])
            w[b] = v
            v = w
        out = -(self.M @ v)
        return out if a is None else out[a]

    def solve(self, r: np.ndarray) -> np.ndarray:
        """The solution (f − 2, n) of the held system for the right-hand side ``r`` (held entries get 0)."""
        N = self.shape[0]
        size, cols = self.size, self.cols
        u = [r[t] if cols[t] is None else r[t, cols[t]] for t in range(N)]
        for t in range(N):                                        # C_t u = X_tᵀ u = B_t L_{t−1}⁻ᵀ u
            if size[t] == 0:
                continue
            if t and size[t - 1]:
                cu = (u[t - 1] @ self._x(t) if self.X is not None
                      else self._couple(t, t - 1, self._tri(t - 1, u[t - 1], True)))
                u[t] = u[t] - cu
            u[t] = self._tri(t, u[t], False)
        for t in range(N - 1, -1, -1):                            # C_{t+1}ᵀ d = X_{t+1} d = L_t⁻¹ B_{t+1}ᵀ d
            if size[t] == 0:
                continue
            if t + 1 < N and size[t + 1]:
                cd = (self._x(t + 1) @ u[t + 1] if self.X is not None
                      else self._tri(t, self._couple(t, t + 1, u[t + 1]), False))
                u[t] = u[t] - cd
            u[t] = self._tri(t, u[t], True)
        out = np.zeros(self.shape)
        for t in range(N):
            if cols[t] is None:
                out[t] = u[t]
            elif size[t]:
                out[t, cols[t]] = u[t]
        return out


def _free_columns(held: np.ndarray) -> tuple:
    """Per frame of ``held`` (N, n): the free entries' indices (None: all of them; one array shared by a run of
    frames with the same held entries, :class:`_Gathers`) and their count."""
    cols, prev = [], None
    same = np.r_[False, np.all(held[1:] == held[:-1], axis=1)].tolist()
    whole = (~held.any(axis=1)).tolist()
    for t, row in enumerate(held):
        if not same[t]:
            prev = None if whole[t] else np.flatnonzero(~row)
        cols.append(prev)
    n = held.shape[1]
    return cols, [n if c is None else int(c.size) for c in cols]


class _Gathers:
    """The blocks ``A[F, F]`` and ``−M[F_s, F_t]`` of :class:`BlockCholesky`, gathered once per run of frames
    with the same free entries (the index arrays are shared along a run: :func:`_free_columns`)."""

    __slots__ = ("A", "negM", "_a", "_m")

    def __init__(self, A: np.ndarray, negM: np.ndarray):
        self.A, self.negM = A, negM
        self._a = self._m = (False, None, None)

    def diagonal(self, c: np.ndarray | None) -> np.ndarray:
        """``A[c, c]`` (``A`` itself for None: copy before writing)."""
        if self._a[0] is not c:
            self._a = (c, self.A if c is None else self.A[np.ix_(c, c)], None)
        return self._a[1]

    def coupling(self, a: np.ndarray | None, b: np.ndarray | None) -> np.ndarray:
        """``−M[a, b]``."""
        if self._m[0] is not a or self._m[1] is not b:
            rows = slice(None) if a is None else a
            block = self.negM[rows] if b is None else self.negM[rows][:, b]
            self._m = (a, b, block)
        return self._m[2]


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
    return system.shape[0] * system.n * (system.n + 1) // 2 * 8 <= BLOCK_BYTES_LIMIT


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
