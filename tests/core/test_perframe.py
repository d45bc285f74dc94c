"""core.retarget.perframe: per-frame bounded, ridge-regularised fits of the sliders (thesis 3.5).

References: ``scipy.optimize.lsq_linear`` (BVLS, an exact active-set method) and OSQP on the ridge-augmented
system, ``np.linalg.lstsq`` without bounds (:mod:`qp_references`).
"""
import numpy as np
import pytest

from core.retarget import fit_frames
from qp_references import bvls_ridge, normalized_B, osqp_qp, ridge_lstsq


@pytest.mark.parametrize("reg", [1e-6, 1e-2, 0.3])
def test_fit_frames_bounded_matches_bvls_and_osqp(reg):
    rng = np.random.default_rng(7)
    m3, n, F = 24, 5, 6
    B = normalized_B(rng, m3, n)
    neutral = rng.standard_normal(m3)
    Wtrue = rng.uniform(-0.6, 1.6, (F, n))                # many weights outside [0, 1]: bounds active
    frames = neutral + Wtrue @ B.T + 0.05 * rng.standard_normal((F, m3))
    lo, hi = np.zeros(n), np.ones(n)
    out = fit_frames(B, neutral, frames, lo, hi, reg=reg)
    assert out.shape == (F, n)
    assert np.all(out >= lo) and np.all(out <= hi)
    n_active = 0
    for f in range(F):
        r = frames[f] - neutral
        ref = bvls_ridge(B, r, reg, lo, hi)
        np.testing.assert_allclose(out[f], ref, rtol=0, atol=1e-6)
        # OSQP on the same QP: ½ wᵀ 2(BᵀB + reg I) w − 2(Bᵀr)ᵀ w
        ref2 = osqp_qp(2 * (B.T @ B + reg * np.eye(n)), -2 * B.T @ r, lo, hi)
        np.testing.assert_allclose(out[f], ref2, rtol=0, atol=1e-6)
        n_active += int(np.sum((ref <= 1e-12) | (ref >= 1 - 1e-12)))
    assert n_active > 0                                   # the bounds really mattered


def test_fit_frames_inactive_bounds_is_ridge_lstsq():
    rng = np.random.default_rng(8)
    m3, n, F = 30, 6, 5
    B = normalized_B(rng, m3, n)
    neutral = rng.standard_normal(m3)
    frames = neutral + rng.standard_normal((F, n)) @ B.T + 0.1 * rng.standard_normal((F, m3))
    for reg in (1e-6, 0.1):
        for lo, hi in ((np.full(n, -np.inf), np.full(n, np.inf)), (np.full(n, -50.0), np.full(n, 50.0))):
            out = fit_frames(B, neutral, frames, lo, hi, reg=reg)
            for f in range(F):
                # normalized_B makes tr(BᵀB)/n = 1, so the relative regulariser equals reg here
                rel = reg * np.trace(B.T @ B) / B.shape[1]
                np.testing.assert_allclose(out[f], ridge_lstsq(B, frames[f] - neutral, rel), rtol=0, atol=1e-6)


def test_fit_frames_unconstrained_equals_lstsq():
    """With a negligible ridge and no active bound the fit is the plain least-squares solution."""
    rng = np.random.default_rng(9)
    m3, n, F = 30, 6, 5
    B = rng.standard_normal((m3, n)) * 3.0
    neutral = rng.standard_normal(m3)
    frames = neutral + rng.standard_normal((F, n)) @ B.T + 0.1 * rng.standard_normal((F, m3))
    out = fit_frames(B, neutral, frames, np.full(n, -np.inf), np.full(n, np.inf), reg=1e-13)
    ref = np.linalg.lstsq(B, (frames - neutral).T, rcond=None)[0].T
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-6)


def test_fit_frames_exact_data_recovered():
    rng = np.random.default_rng(10)
    B = normalized_B(rng, 18, 4)
    neutral = rng.standard_normal(18)
    W = rng.uniform(0.1, 0.9, (7, 4))
    out = fit_frames(B, neutral, neutral + W @ B.T, np.zeros(4), np.ones(4), reg=1e-12)
    np.testing.assert_allclose(out, W, rtol=0, atol=1e-6)


def test_fit_frames_tiny_ridge_is_still_the_least_squares_fit():
    rng = np.random.default_rng(10)
    B = normalized_B(rng, 18, 4)
    neutral = rng.standard_normal(18)
    W = rng.uniform(0.1, 0.9, (7, 4))
    # exact data inside the box: the minimiser of ‖Bw − r‖² + 1e-16‖w‖² is W up to ~1e-16
    out = fit_frames(B, neutral, neutral + W @ B.T, np.zeros(4), np.ones(4), reg=1e-16)
    np.testing.assert_allclose(out, W, rtol=0, atol=1e-6)


def test_fit_frames_documented_objective_unnormalized_B():
    """Documented objective: ‖Bw − r‖² + reg·(tr(BᵀB)/n)·‖w‖² (unit-independent regulariser)."""
    rng = np.random.default_rng(11)
    B = 10.0 * rng.standard_normal((20, 4))                # trace(BᵀB)/n ≈ 2000
    neutral = rng.standard_normal(20)
    frames = neutral + rng.uniform(0, 1, (3, 4)) @ B.T + rng.standard_normal((3, 20))
    reg = 1e-2
    out = fit_frames(B, neutral, frames, np.full(4, -np.inf), np.full(4, np.inf), reg=reg)
    rel = reg * np.trace(B.T @ B) / B.shape[1]
    for f in range(3):
        np.testing.assert_allclose(out[f], ridge_lstsq(B, frames[f] - neutral, rel), rtol=0, atol=1e-6)


def test_batched_active_set_gives_each_frame_s_bvls_minimiser_with_one_sided_and_infinite_bounds():
    from core.retarget.perframe import batched_active_set
    rng = np.random.default_rng(24)
    m3, n, F = 30, 8, 300
    B = normalized_B(rng, m3, n)
    S = rng.uniform(-0.8, 1.8, (F, n)) @ B.T + 0.05 * rng.standard_normal((F, m3))
    a = 1e-3
    H = 2.0 * (B.T @ B + a * np.eye(n))
    lo = np.array([0.0, 0.0, -np.inf, 0.0, -1.0, 0.0, -np.inf, 0.2])
    hi = np.array([1.0, np.inf, 1.0, 1.0, 0.5, 1.0, np.inf, 0.8])
    X, done = batched_active_set(H, 2.0 * (S @ B), lo, hi)
    assert done.all() and np.all(X >= lo) and np.all(X <= hi)
    A = np.vstack([B, np.sqrt(a) * np.eye(n)])
    from scipy.optimize import lsq_linear
    for f in range(F):
        ref = lsq_linear(A, np.concatenate([S[f], np.zeros(n)]), bounds=(lo, hi), method="bvls", tol=1e-12).x
        np.testing.assert_allclose(X[f], ref, rtol=0, atol=1e-9)
    held = (X == lo) | (X == hi)
    assert held.sum() > F and len({r.tobytes() for r in held}) > 10          # many distinct held sets


def test_batched_active_set_hands_back_frames_it_does_not_settle():
    from core.retarget.perframe import batched_active_set
    rng = np.random.default_rng(3)
    n = 6
    U = np.linalg.qr(rng.normal(size=(n, n)))[0]
    H = U @ np.diag(np.geomspace(10.0, 0.01, n)) @ U.T
    G = rng.normal(size=(50, n)) * 5.0
    X, done = batched_active_set(H, G, np.zeros(n), np.ones(n), max_iter=1)   # one pass: only the interior ones
    free = np.linalg.solve(H, G.T).T
    inside = np.all((free >= 0) & (free <= 1), axis=1)
    np.testing.assert_array_equal(done, inside)
    assert not inside.all()
