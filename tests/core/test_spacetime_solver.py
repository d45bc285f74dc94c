"""core.retarget.spacetime_solver: space-time cloning with and without slider bounds (thesis ch. 5).

Every reference is built here independently of the code under test: the explicit sparse normal equations
``(DᵀD ⊗ BᵀB + λ I ⊗ diag(1/σ²)) vec(W) = vec(DᵀD S B)`` (row-major vec) restricted to the interior frames, the
two boundary frames moved to the right-hand side, solved with ``scipy.sparse.linalg.spsolve``; the bounded problem
is the same QP handed to OSQP (and quadprog) (:mod:`qp_references`).
"""
import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

from core.result import ShapeSpaceError
from core.retarget import fit_frames, spacetime
from core.retarget.spacetime_solver import END_RIDGE
from qp_references import bvls_ridge, normalized_B, osqp_qp, quadprog_box, rel, ridge_lstsq, smooth_weights


def spacetime_system(B, neutral, frames, sigma, lam, first, last):
    """Explicit Kronecker normal equations over the interior frames.

    Unknown: row-major vec of W (F × n), index f·n + k.  The objective
    ‖D(W Bᵀ − S)‖² + λ Σ_interior Σ_k (w_fk/σ_k)² has the normal matrix
    K = DᵀD ⊗ BᵀB + λ I ⊗ diag(1/σ²) and right-hand side vec(DᵀD S B).
    Returns (K_II, b_I) with the boundary frames moved to the right-hand side:  K_II x = b_I.
    """
    S = np.asarray(frames, float) - np.asarray(neutral, float)
    F, n = S.shape[0], B.shape[1]
    D = sp.diags([-np.ones(F - 1), np.ones(F - 1)], [0, 1], shape=(F - 1, F), format="csr")
    DtD = (D.T @ D).tocsr()
    K = sp.kron(DtD, sp.csr_matrix(B.T @ B)) + lam * sp.kron(sp.identity(F), sp.diags(1.0 / sigma ** 2))
    K = K.tocsc()
    rhs = np.asarray(DtD @ S @ B).reshape(-1)
    interior = np.arange(n, (F - 1) * n)
    boundary = np.concatenate([np.arange(n), np.arange((F - 1) * n, F * n)])
    wB = np.concatenate([first, last])
    K_II = K[interior][:, interior]
    K_IB = K[interior][:, boundary]
    return K_II, rhs[interior] - K_IB @ wB


def spacetime_reference(B, neutral, frames, sigma, lam, first, last):
    K_II, b = spacetime_system(B, neutral, frames, sigma, lam, first, last)
    x = spsolve(K_II.tocsc(), b)
    F, n = frames.shape[0], B.shape[1]
    W = np.empty((F, n))
    W[0], W[-1] = first, last
    W[1:-1] = x.reshape(F - 2, n)
    return W


def spacetime_objective(W, B, neutral, frames, sigma, lam):
    """‖D(W Bᵀ − S)‖² + λ Σ_interior (w/σ)², evaluated directly (no normal equations)."""
    S = frames - neutral
    R = np.diff(W @ B.T - S, axis=0)
    return float(np.sum(R ** 2) + lam * np.sum((W[1:-1] / sigma) ** 2))


def st_problem(seed, F, n, m3, noise=0.05, amp=1.0):
    rng = np.random.default_rng(seed)
    B = rng.standard_normal((m3, n))
    neutral = rng.standard_normal(m3)
    W = smooth_weights(rng, F, n, amp)
    frames = neutral + W @ B.T + noise * rng.standard_normal((F, m3))
    sigma = rng.uniform(0.3, 2.0, n)
    return rng, B, neutral, frames, sigma, W


@pytest.mark.parametrize("seed, F, n, m3, lam", [
    (20, 40, 5, 30, 1e-3),
    (21, 25, 4, 12, 1.0),
    (22, 3, 3, 9, 1e-2),         # a single interior frame
    (23, 4, 6, 15, 1e-3),
    (24, 30, 8, 6, 1e-2),        # m3 < n: BᵀB singular, zero modes held only by the regulariser
])
def test_spacetime_matches_kronecker_normal_equations(seed, F, n, m3, lam):
    rng, B, neutral, frames, sigma, _ = st_problem(seed, F, n, m3)
    first = rng.uniform(0, 1, n)
    last = rng.uniform(0, 1, n)
    res = spacetime(B, neutral, frames, sigma, lam=lam, first=first, last=last)
    assert res.status == 0 and res.iterations == 0
    ref = spacetime_reference(B, neutral, frames, sigma, lam, first, last)
    assert rel(res.weights[1:-1], ref[1:-1]) <= 1e-9
    np.testing.assert_array_equal(res.weights[0], first)           # boundary frames exactly as given
    np.testing.assert_array_equal(res.weights[-1], last)


def test_spacetime_reference_minimises_the_objective():
    """Sanity of the Kronecker reference itself (and of the code): random interior perturbations only
    increase the directly evaluated objective."""
    rng, B, neutral, frames, sigma, _ = st_problem(25, 15, 3, 9)
    first, last = rng.uniform(0, 1, 3), rng.uniform(0, 1, 3)
    res = spacetime(B, neutral, frames, sigma, lam=1e-2, first=first, last=last)
    f0 = spacetime_objective(res.weights, B, neutral, frames, sigma, 1e-2)
    for _ in range(20):
        W = res.weights.copy()
        W[1:-1] += 1e-3 * rng.standard_normal(W[1:-1].shape)
        assert spacetime_objective(W, B, neutral, frames, sigma, 1e-2) > f0


def test_spacetime_default_ends_are_per_frame_fits():
    rng = np.random.default_rng(26)
    F, n, m3 = 20, 4, 15
    B = normalized_B(rng, m3, n)
    neutral = rng.standard_normal(m3)
    frames = neutral + smooth_weights(rng, F, n) @ B.T + 0.05 * rng.standard_normal((F, m3))
    sigma = rng.uniform(0.5, 1.5, n)
    res = spacetime(B, neutral, frames, sigma, lam=1e-3)
    # per-frame fit of the end frames in the whitened variables w/σ (ridge END_RIDGE·tr(ΣBᵀBΣ)/n on w/σ, the
    # interior's weighting, so ties split alike; no active bound), computed independently by lstsq
    Bs = B * sigma
    a = END_RIDGE * np.trace(Bs.T @ Bs) / n
    for row in (0, -1):
        want = ridge_lstsq(Bs, frames[row] - neutral, a) * sigma
        np.testing.assert_allclose(res.weights[row], want, rtol=0, atol=1e-9)
    # exactly: the per-frame fit in the whitened variables w/σ (ties split like the interior's σ-weighted ridge)
    ends = fit_frames(B * sigma, neutral, frames[[0, -1]], np.full(n, -1e6) / sigma, np.full(n, 1e6) / sigma,
                      reg=END_RIDGE) * sigma
    np.testing.assert_allclose(res.weights[[0, -1]], ends, rtol=0, atol=1e-12)
    # the interior is the Kronecker solution with those ends
    ref = spacetime_reference(B, neutral, frames, sigma, 1e-3, res.weights[0], res.weights[-1])
    assert rel(res.weights, ref) <= 1e-9
    # only one end given: the other is still the per-frame fit
    res2 = spacetime(B, neutral, frames, sigma, lam=1e-3, first=np.zeros(n))
    np.testing.assert_array_equal(res2.weights[0], np.zeros(n))
    np.testing.assert_allclose(res2.weights[-1], ends[1], rtol=0, atol=1e-12)


def test_spacetime_recovers_smooth_weights_without_regularisation():
    rng = np.random.default_rng(27)
    F, n, m3 = 50, 5, 24
    B = rng.standard_normal((m3, n))
    neutral = rng.standard_normal(m3)
    W = smooth_weights(rng, F, n)
    frames = neutral + W @ B.T                           # noise-free, S = b0 + W Bᵀ
    sigma = rng.uniform(0.5, 2.0, n)
    res = spacetime(B, neutral, frames, sigma, lam=1e-12, first=W[0], last=W[-1])
    np.testing.assert_allclose(res.weights, W, rtol=0, atol=1e-6)
    # default ends: the per-frame fits are biased by the ridge a = 1e-6·tr(BᵀB)/n; with orthonormal
    # columns (BᵀB = I, a = 1e-6) the bias is a/(1 + a)·|w| < 1e-6 here (|w| < 1), and with λ → 0
    # derivative matching carries the end errors linearly inward, so the whole solution stays within 1e-6
    Bn = np.linalg.qr(rng.standard_normal((m3, n)))[0]
    frames_n = neutral + W @ Bn.T
    res_d = spacetime(Bn, neutral, frames_n, sigma, lam=1e-12)
    np.testing.assert_allclose(res_d.weights, W, rtol=0, atol=1e-6)


def test_spacetime_offset_invariance():
    rng, B, neutral, frames, sigma, _ = st_problem(28, 20, 4, 12)
    c = rng.standard_normal(12) * 5.0
    a = spacetime(B, neutral, frames, sigma, lam=1e-2)
    b = spacetime(B, neutral + c, frames + c, sigma, lam=1e-2)
    np.testing.assert_allclose(b.weights, a.weights, rtol=0, atol=1e-9 * np.abs(a.weights).max())
    # with the ends fixed, only temporal differences of S matter: a constant offset of the source frames
    # alone (neutral unchanged) leaves the solution unchanged as well
    first, last = a.weights[0].copy(), a.weights[-1].copy()
    c2 = spacetime(B, neutral, frames + c, sigma, lam=1e-2, first=first, last=last)
    np.testing.assert_allclose(c2.weights, a.weights, rtol=0, atol=1e-9 * np.abs(a.weights).max())


@pytest.mark.parametrize("F", [1, 2])
def test_spacetime_too_few_frames(F):
    rng = np.random.default_rng(29)
    with pytest.raises(ShapeSpaceError) as exc:
        spacetime(rng.standard_normal((6, 2)), np.zeros(6), rng.standard_normal((F, 6)), np.ones(2))
    assert exc.value.code == "too_short"


@pytest.mark.parametrize("sigma", [[1.0, 0.0], [1.0, -0.5], [np.inf, 1.0], [np.nan, 1.0]])
def test_spacetime_bad_sigma(sigma):
    rng = np.random.default_rng(30)
    with pytest.raises(ShapeSpaceError) as exc:
        spacetime(rng.standard_normal((6, 2)), np.zeros(6), rng.standard_normal((5, 6)), np.array(sigma))
    assert exc.value.code == "range"


def test_spacetime_bounded_within_bounds_and_matches_osqp():
    # Small problem F=12, n=3, m3=12, bounds active.  The reference is the same QP
    #   min xᵀ K_II x − 2 bᵀ x,  lo ≤ x ≤ hi   (x = interior weights, row-major)
    # solved by OSQP at eps 1e-10 with polishing and cross-checked with quadprog (exact active set).
    # The objective is compared with a relative gap of 1e-4 (the convergence test is on the natural
    # residual, not the objective).
    rng, B, neutral, frames, sigma, _ = st_problem(31, 12, 3, 12, noise=0.05, amp=1.8)
    lam = 1e-2
    n, F = 3, 12
    lo, hi = np.zeros(n), np.ones(n)
    first, last = np.array([0.2, 0.9, 0.5]), np.array([0.7, 0.1, 1.0])
    res = spacetime(B, neutral, frames, sigma, lam=lam, first=first, last=last, lo=lo, hi=hi)
    assert res.status == 0 and res.iterations > 0
    W = res.weights
    assert np.all(W >= lo) and np.all(W <= hi)
    np.testing.assert_array_equal(W[0], first)
    np.testing.assert_array_equal(W[-1], last)

    K_II, b = spacetime_system(B, neutral, frames, sigma, lam, first, last)
    P, q = 2 * K_II.toarray(), -2 * b
    lo_x, hi_x = np.tile(lo, F - 2), np.tile(hi, F - 2)
    x_osqp = osqp_qp(P, q, lo_x, hi_x)
    x_qp = quadprog_box(P, q, lo_x, hi_x)
    np.testing.assert_allclose(x_osqp, x_qp, rtol=0, atol=1e-7)        # the two references agree

    def assemble(x):
        Wr = np.empty((F, n))
        Wr[0], Wr[-1] = first, last
        Wr[1:-1] = np.clip(x, lo_x, hi_x).reshape(F - 2, n)
        return Wr

    f_ref = spacetime_objective(assemble(x_qp), B, neutral, frames, sigma, lam)
    f_code = spacetime_objective(W, B, neutral, frames, sigma, lam)
    assert f_code >= f_ref * (1 - 1e-12)                      # nobody beats the exact QP optimum
    assert (f_code - f_ref) / f_ref <= 1e-4
    # the bounds really mattered: the unbounded solution leaves the box
    free = spacetime(B, neutral, frames, sigma, lam=lam, first=first, last=last)
    assert np.any(free.weights < lo - 1e-3) or np.any(free.weights > hi + 1e-3)


@pytest.mark.parametrize("route", ["capacitance", "banded", "cg"])
def test_spacetime_bounded_every_newton_step_matches_quadprog(route, monkeypatch):
    # A mid-size problem (F=60, n=5) where many entries clip: the three ways of computing the reduced
    # Newton step — capacitance (small active sets), banded Cholesky (large ones), preconditioned CG
    # (huge problems) — each reach quadprog's exact active-set optimum of the explicit Kronecker QP.
    import core.retarget.spacetime_solver as solver
    max_exact_active = 1000 if route == "capacitance" else 0
    if route == "cg":
        monkeypatch.setattr(solver, "BANDED_FLOP_LIMIT", 0.0)
    rng, B, neutral, frames, sigma, _ = st_problem(7, 60, 5, 15, noise=0.05, amp=2.5)
    lam, n, F = 1e-3, 5, 60
    lo, hi = np.full(n, -0.2), np.full(n, 0.6)
    first, last = np.clip(rng.normal(size=n), lo, hi), np.clip(rng.normal(size=n), lo, hi)
    res = spacetime(B, neutral, frames, sigma, lam=lam, first=first, last=last, lo=lo, hi=hi,
                    max_exact_active=max_exact_active)
    assert res.status == 0, res.message
    K_II, b = spacetime_system(B, neutral, frames, sigma, lam, first, last)
    lo_x, hi_x = np.tile(lo, F - 2), np.tile(hi, F - 2)
    x_qp = quadprog_box(2 * K_II.toarray(), -2 * b, lo_x, hi_x)
    clipped = np.sum((x_qp <= lo_x + 1e-9) | (x_qp >= hi_x - 1e-9))
    assert clipped > 20                                      # the bounds really bind
    np.testing.assert_allclose(res.weights[1:-1].ravel(), x_qp, rtol=0, atol=1e-6)


def test_spacetime_bounded_default_ends_are_bounded_fits():
    rng, B, neutral, frames, sigma, _ = st_problem(32, 15, 3, 12, amp=1.8)
    lo, hi = np.zeros(3), np.ones(3)
    res = spacetime(B, neutral, frames, sigma, lam=1e-2, lo=lo, hi=hi)
    assert res.status == 0
    Bs = B * sigma                                             # the end frames' fit is on w/σ (see _end_frames)
    a = END_RIDGE * np.trace(Bs.T @ Bs) / 3
    for row in (0, -1):
        want = bvls_ridge(Bs, frames[row] - neutral, a, lo / sigma, hi / sigma) * sigma
        np.testing.assert_allclose(res.weights[row], want, rtol=0, atol=1e-6)
    assert np.all(res.weights >= lo) and np.all(res.weights <= hi)


def test_spacetime_bounded_exactly_within_bounds_nonunit_sigma():
    lo_v, hi_v = -0.3, 0.7
    # pure float arithmetic, independent of the code: slider scales whose division/multiplication round
    # trip overshoots the bound, i.e. (hi/σ)·σ > hi or (lo/σ)·σ < lo
    grid = np.linspace(0.1, 3.0, 2901)
    over_hi = grid[(hi_v / grid) * grid > hi_v]
    under_lo = grid[(lo_v / grid) * grid < lo_v]
    assert over_hi.size and under_lo.size
    n = 4
    sigma = np.array([over_hi[0], over_hi[-1], under_lo[0], under_lo[-1]])
    rng = np.random.default_rng(33)
    F, m3 = 20, 12
    B = rng.standard_normal((m3, n))
    neutral = rng.standard_normal(m3)
    t = np.linspace(0.0, 1.0, F)[:, None]
    W = 0.2 + 1.5 * np.sin(2 * np.pi * t + np.arange(n))       # swings well past both bounds
    frames = neutral + W @ B.T
    lo, hi = np.full(n, lo_v), np.full(n, hi_v)
    res = spacetime(B, neutral, frames, sigma, lam=1e-3, lo=lo, hi=hi)
    assert res.status == 0
    assert np.all(res.weights >= lo), (res.weights - lo).min()
    assert np.all(res.weights <= hi), (res.weights - hi).max()


def test_spacetime_bounded_equals_unbounded_when_inactive():
    rng, B, neutral, frames, sigma, _ = st_problem(37, 30, 4, 15)
    lam = 1e-2
    free = spacetime(B, neutral, frames, sigma, lam=lam)
    lo, hi = np.full(4, -10.0), np.full(4, 10.0)
    assert np.all(free.weights > lo + 1) and np.all(free.weights < hi - 1)
    boxed = spacetime(B, neutral, frames, sigma, lam=lam, lo=lo, hi=hi)
    assert boxed.status == 0
    assert rel(boxed.weights, free.weights) <= 1e-5
    first, last = free.weights[0], free.weights[-1]
    boxed2 = spacetime(B, neutral, frames, sigma, lam=lam, first=first, last=last, lo=lo, hi=hi)
    assert boxed2.status == 0
    assert rel(boxed2.weights, free.weights) <= 1e-5
