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
``−M`` restricted to each frame's free entries, packed; O(Σ |F_t|³) flops in
BLAS-3 blocks, memory Σ |F_t|² / 2, linear in the take length).  The held set is found by

- :func:`peak_active_set` (first): from the unbounded solution, hold the
  deepest part of every run of violated frames of a slider (entries violated by at least
  :data:`PEAK_FRACTION` of the run's deepest) and release held
  entries whose multiplier has the wrong sign.  Holding all violated entries
  (the clipped unbounded solution) overshoots: on real takes most of them end
  up free, lifted by the velocity coupling (facecap→FBHead: 7,231 violated,
  1,059 active; the 1,640-frame take: 12,997 and 2,612), and a primal–dual
  active-set method then needs 23–88 iterations to shed them; holding each
  run's deepest entry alone needs 8–14 (13 on 36,000 frames onto FBHead), its deepest half 3;
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

Modules (as SciPy's ``optimize/_lsq``): :mod:`.system` (the system and its operator), :mod:`.kernels` (the
exact reduced Newton steps), :mod:`.bounded` (the bounded methods) and :mod:`.solve` (the dispatcher,
:func:`spacetime`); every public name is re-exported here.
"""
from __future__ import annotations

from .bounded import (
                      PEAK_FRACTION,
                      PEAK_PATIENCE,
                      SHALLOW_VIOLATION,
                      active_set,
                      clipped_solve,
                      interior_point,
                      peak_active_set,
                      projected_newton,
                      run_peaks,
                      shallow_violation,
)
from .kernels import (
                      BANDED_FLOP_LIMIT,
                      BLOCK_BYTES_LIMIT,
                      BLOCK_KEEP_BYTES,
                      PROGRESS_BLOCKS,
                      BlockCholesky,
                      banded_step,
                      block_fits,
                      block_step,
                      capacitance_limit,
                      capacitance_step,
                      cg_step,
                      reduced_step,
)
from .solve import DEGENERATE_RATIO, DRIFT_BETA, END_RIDGE, SpacetimeResult, spacetime
from .system import CHUNK_ROWS, GREEN_TABLE_LIMIT, GreenTables, SpacetimeSystem

__all__ = ["spacetime", "SpacetimeResult", "DRIFT_BETA", "END_RIDGE", "DEGENERATE_RATIO", "SpacetimeSystem",
           "GreenTables", "GREEN_TABLE_LIMIT", "CHUNK_ROWS", "reduced_step", "capacitance_step", "banded_step",
           "cg_step", "BlockCholesky", "block_step", "capacitance_limit", "block_fits", "BANDED_FLOP_LIMIT",
           "BLOCK_BYTES_LIMIT", "PROGRESS_BLOCKS", "BLOCK_KEEP_BYTES", "clipped_solve", "peak_active_set",
           "interior_point", "active_set", "projected_newton", "run_peaks", "shallow_violation", "PEAK_PATIENCE",
           "PEAK_FRACTION", "SHALLOW_VIOLATION"]
