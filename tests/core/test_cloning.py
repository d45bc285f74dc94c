"""core.retarget (cloning, perframe, spacetime_solver, landmarks) and core.keyreduce: expression
cloning, per-frame fits, space-time cloning (thesis ch. 5), key reduction, Procrustes and landmark warps (thesis 3.5).

Every reference is built here independently of the code under test:

- space-time cloning: the explicit sparse normal equations ``(DᵀD ⊗ BᵀB + λ I ⊗ diag(1/σ²)) vec(W)
  = vec(DᵀD S B)`` (row-major vec) restricted to the interior frames, the two boundary frames moved to
  the right-hand side, solved with ``scipy.sparse.linalg.spsolve``; the bounded problem is the same QP
  handed to OSQP (and quadprog);
- per-frame fits: ``scipy.optimize.lsq_linear`` (BVLS, an exact active-set method) and OSQP on the
  ridge-augmented system, ``np.linalg.lstsq`` without bounds;
- key reduction: brute force over all key subsets; Procrustes: ``scipy Rotation.align_vectors`` (Kabsch);
  nearest neighbours: a dense distance matrix.
"""
import itertools

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.optimize import lsq_linear
from scipy.sparse.linalg import spsolve
from scipy.spatial.transform import Rotation

from core.keyreduce import curve_slopes, hermite, reduce_keys, reduce_keys_bezier
from core.retarget import (closest_points, cloning_matrix, copy_weights, fit_frames, key_poses, landmark_layout,
                           landmark_warp, peak_landmarks, procrustes, spacetime)
from core.retarget.spacetime_solver import END_RIDGE
from core.result import ShapeSpaceError


# --------------------------------------------------------------------------- helpers
def normalized_B(rng, m3, n):
    """Random (m3, n) target delta matrix scaled so trace(BᵀB)/n == 1.

    With this scaling the documented fit objective ``‖Bw − r‖² + reg‖w‖²`` and the implementation's
    trace-relative ridge ``reg·tr(BᵀB)/n`` coincide, so references can use ``reg`` as written.
    """
    B = rng.standard_normal((m3, n))
    return B * np.sqrt(n / np.trace(B.T @ B))


def smooth_weights(rng, F, n, amp=1.0):
    t = np.linspace(0.0, 1.0, F)[:, None]
    freq = rng.uniform(0.5, 2.0, n)
    phase = rng.uniform(0, 2 * np.pi, n)
    return amp * (0.5 + 0.4 * np.sin(2 * np.pi * freq * t + phase))


def ridge_lstsq(B, r, a):
    """min ‖Bw − r‖² + a‖w‖² by plain least squares on the augmented system [B; √a I]."""
    n = B.shape[1]
    A = np.vstack([B, np.sqrt(a) * np.eye(n)])
    return np.linalg.lstsq(A, np.concatenate([r, np.zeros(n)]), rcond=None)[0]


def bvls_ridge(B, r, a, lo, hi):
    n = B.shape[1]
    A = np.vstack([B, np.sqrt(a) * np.eye(n)])
    res = lsq_linear(A, np.concatenate([r, np.zeros(n)]), bounds=(lo, hi), method="bvls", tol=1e-14,
                     lsmr_tol=None)
    assert res.status > 0, res.message
    return res.x


def osqp_qp(P, q, lo, hi):
    """min ½xᵀPx + qᵀx, lo ≤ x ≤ hi with OSQP at eps 1e-10 plus polishing (asserted)."""
    osqp = pytest.importorskip("osqp")  # the independent reference: skipped where not installed
    n = P.shape[0]
    solver = osqp.OSQP()
    solver.setup(sp.triu(sp.csc_matrix(P), format="csc"), q, sp.identity(n, format="csc"), lo, hi,
                 eps_abs=1e-10, eps_rel=1e-10, polishing=True, max_iter=200000, verbose=False)
    res = solver.solve(raise_error=False)
    assert res.info.status == "solved", res.info.status
    assert res.info.status_polish in (1, 2), "OSQP reference did not polish"
    return np.asarray(res.x)


def quadprog_box(P, q, lo, hi):
    """min ½xᵀPx + qᵀx with finite box bounds (Goldfarb–Idnani: Cᵀx ≥ b)."""
    quadprog = pytest.importorskip("quadprog")  # the independent reference: skipped where not installed
    n = P.shape[0]
    I = np.eye(n)
    C = np.hstack([I, -I])
    b = np.concatenate([lo, -hi])
    return quadprog.solve_qp(np.asarray(P, dtype=float), -q, C, b, 0)[0]


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


def rel(a, b):
    return float(np.linalg.norm(a - b) / max(np.linalg.norm(b), 1e-300))


# --------------------------------------------------------------------------- copy_weights
def test_copy_weights_gain_offset():
    rng = np.random.default_rng(1)
    S = rng.uniform(0, 1, (7, 3))
    gain = np.array([2.0, 0.5, -1.0, 3.0])
    offset = np.array([0.1, 0.0, 0.25, -0.5])
    out = copy_weights(S, [(0, 2), (2, 0), (1, 3)], 4, gain=gain, offset=offset)
    assert out.shape == (7, 4)
    np.testing.assert_allclose(out[:, 2], -1.0 * S[:, 0] + 0.25, atol=1e-15)
    np.testing.assert_allclose(out[:, 0], 2.0 * S[:, 2] + 0.1, atol=1e-15)
    np.testing.assert_allclose(out[:, 3], 3.0 * S[:, 1] - 0.5, atol=1e-15)
    np.testing.assert_array_equal(out[:, 1], 0.0)                 # unmapped target channel stays 0


def test_copy_weights_plain_copy():
    S = np.array([[0.1, 0.2], [0.3, 0.4], [0.5, 0.6]])
    out = copy_weights(S, [(1, 0)], 3)
    np.testing.assert_array_equal(out, [[0.2, 0, 0], [0.4, 0, 0], [0.6, 0, 0]])


def test_copy_weights_clamping():
    S = np.array([[-0.5, 0.2], [0.5, 1.4], [1.5, 0.9]])
    lo, hi = np.array([0.0, 0.0]), np.array([1.0, 1.2])
    out = copy_weights(S, [(0, 0), (1, 1)], 2, gain=np.array([1.0, 1.0]), offset=np.array([0.0, 0.0]),
                       lo=lo, hi=hi)
    np.testing.assert_array_equal(out, [[0.0, 0.2], [0.5, 1.2], [1.0, 0.9]])
    only_hi = copy_weights(S, [(0, 0), (1, 1)], 2, hi=hi)
    np.testing.assert_array_equal(only_hi, [[-0.5, 0.2], [0.5, 1.2], [1.0, 0.9]])
    only_lo = copy_weights(S, [(0, 0), (1, 1)], 2, lo=lo)
    np.testing.assert_array_equal(only_lo, [[0.0, 0.2], [0.5, 1.4], [1.5, 0.9]])


@pytest.mark.parametrize("mapping", [[], ()])
def test_copy_weights_empty_mapping(mapping):
    with pytest.raises(ShapeSpaceError) as exc:
        copy_weights(np.zeros((3, 2)), mapping, 2)
    assert exc.value.code == "no_mapping"


# --------------------------------------------------------------------------- cloning_matrix
@pytest.mark.parametrize("c, ns, nt", [(12, 5, 3), (5, 5, 4), (40, 8, 10)])
def test_cloning_matrix_exact_recovery(c, ns, nt):
    rng = np.random.default_rng(c * 100 + ns)
    Ws = rng.standard_normal((c, ns))
    E = rng.standard_normal((ns, nt))
    Wt = Ws @ E
    E_hat = cloning_matrix(Ws, Wt)
    assert E_hat.shape == (ns, nt)
    # The documented tiny ridge ε = 1e-8·tr(A)/n (A = WsᵀWs) biases the exact answer by
    # Ê − E = −ε (A + εI)⁻¹ E, so ‖Ê − E‖ ≤ ε/λ_min(A)·‖E‖ (bound computed here, not tuned).
    A = Ws.T @ Ws
    eps = 1e-8 * np.trace(A) / ns
    bound = eps / np.linalg.eigvalsh(A)[0] * np.linalg.norm(E, 2)
    assert np.linalg.norm(E_hat - E, 2) <= 1.01 * bound + 1e-12
    np.testing.assert_allclose(E_hat, E, rtol=0, atol=1e-6)


def test_cloning_matrix_least_squares_with_noise():
    rng = np.random.default_rng(3)
    Ws = rng.standard_normal((30, 4))
    Wt = Ws @ rng.standard_normal((4, 2)) + 0.1 * rng.standard_normal((30, 2))
    E_ls = np.linalg.lstsq(Ws, Wt, rcond=None)[0]
    np.testing.assert_allclose(cloning_matrix(Ws, Wt), E_ls, rtol=0, atol=1e-6)


def test_cloning_matrix_too_few_pairs():
    rng = np.random.default_rng(4)
    with pytest.raises(ShapeSpaceError) as exc:
        cloning_matrix(rng.standard_normal((4, 5)), rng.standard_normal((4, 3)))
    assert exc.value.code == "too_few"


def test_cloning_matrix_shape_mismatch():
    with pytest.raises(ShapeSpaceError) as exc:
        cloning_matrix(np.zeros((6, 3)), np.zeros((5, 2)))
    assert exc.value.code == "shape"


# --------------------------------------------------------------------------- key_poses
def test_key_poses_constructed_principal_axes():
    """Data built with known principal axes Q and orthonormal zero-mean scores Z: the key frames are the
    arg max / arg min of each score column (sign of a PC only swaps max and min)."""
    rng = np.random.default_rng(5)
    F, n = 60, 6
    raw = rng.standard_normal((F, n))
    Z, _ = np.linalg.qr(raw - raw.mean(axis=0))          # orthonormal, zero-mean columns
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    scales = np.array([10.0, 6.0, 3.0, 1.0, 0.5, 0.2])
    W = rng.uniform(0, 1, n) + (Z * scales) @ Q.T
    picks = key_poses(W, components=3)
    expected = []
    for j in range(3):
        for k in (int(np.argmax(Z[:, j])), int(np.argmin(Z[:, j]))):
            if k not in expected:
                expected.append(k)
    assert len(picks) == len(set(picks.tolist()))
    assert set(picks.tolist()) == set(expected)
    # PC by PC: the first two picks are the extremes of PC 1 in some order
    assert set(picks[:2].tolist()) == {int(np.argmax(Z[:, 0])), int(np.argmin(Z[:, 0]))}


@pytest.mark.parametrize("components", [1, 2, 4])
def test_key_poses_against_svd(components):
    rng = np.random.default_rng(6 + components)
    W = rng.uniform(0, 1, (80, 9)) @ np.diag(np.linspace(2, 0.2, 9))
    C = W - W.mean(axis=0)
    evals, evecs = np.linalg.eigh(C.T @ C)             # covariance eigenvectors, largest last
    P = C @ evecs[:, ::-1][:, :components]
    expected = {int(i) for j in range(components) for i in (np.argmax(P[:, j]), np.argmin(P[:, j]))}
    picks = key_poses(W, components=components)
    assert picks.dtype.kind == "i"
    assert set(picks.tolist()) == expected
    assert len(picks) == len(expected)


# --------------------------------------------------------------------------- fit_frames
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


# --------------------------------------------------------------------------- spacetime (unbounded)
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


# --------------------------------------------------------------------------- spacetime (bounded)
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


# --------------------------------------------------------------------------- reduce_keys
def keys_valid(t, v, keys, tol):
    # 1e-12 absolute slack only absorbs rounding between np.interp and the solver's slope arithmetic
    return bool(np.all(np.abs(np.interp(t, t[keys], v[keys]) - v) <= tol + 1e-12))


def brute_force_min_keys(t, v, tol):
    n = t.size
    inner = list(range(1, n - 1))
    for size in range(0, n - 1):
        for combo in itertools.combinations(inner, size):
            keys = np.array([0, *combo, n - 1])
            if keys_valid(t, v, keys, tol):
                return size + 2
    raise AssertionError("unreachable: all samples are always valid")


@pytest.mark.parametrize("seed", range(12))
def test_reduce_keys_optimal_against_brute_force(seed):
    rng = np.random.default_rng(100 + seed)
    n = int(rng.integers(3, 13))
    t = np.cumsum(rng.uniform(0.2, 1.5, n))
    v = np.cumsum(rng.standard_normal(n)) * 0.3
    for tol in (0.0, 0.05, 0.2, 0.6):
        keys = reduce_keys(t, v, tol)
        assert keys[0] == 0 and keys[-1] == n - 1
        assert np.all(np.diff(keys) > 0)
        assert keys_valid(t, v, keys, tol)
        assert keys.size == brute_force_min_keys(t, v, tol)


def test_reduce_keys_long_curve_valid():
    rng = np.random.default_rng(200)
    t = np.arange(600) / 24.0
    v = np.cumsum(rng.standard_normal(600)) * 0.05 + np.sin(t)
    for tol in (0.01, 0.05, 0.2):
        keys = reduce_keys(t, v, tol)
        assert keys[0] == 0 and keys[-1] == 599
        assert keys_valid(t, v, keys, tol)
        assert 2 < keys.size < 600


def test_reduce_keys_straight_line_and_constant():
    t = np.arange(10, dtype=float)
    np.testing.assert_array_equal(reduce_keys(t, 3.0 * t - 2.0, 0.0), [0, 9])     # exact dyadic values
    np.testing.assert_array_equal(reduce_keys(t, np.full(10, 0.7), 0.0), [0, 9])
    np.testing.assert_array_equal(reduce_keys(t * 0.5, 0.25 * t + 1.0, 0.0), [0, 9])


def test_reduce_keys_corner_kept():
    t = np.arange(7, dtype=float)
    v = np.array([0, 1, 2, 3, 2, 1, 0], dtype=float)                  # a tent: the apex is needed
    np.testing.assert_array_equal(reduce_keys(t, v, 0.0), [0, 3, 6])
    np.testing.assert_array_equal(reduce_keys(t, v, 0.49), [0, 3, 6])
    np.testing.assert_array_equal(reduce_keys(t, v, 3.0), [0, 6])


def test_reduce_keys_tiny_inputs():
    np.testing.assert_array_equal(reduce_keys([0.0], [1.0], 0.1), [0])
    np.testing.assert_array_equal(reduce_keys([0.0, 1.0], [1.0, 5.0], 0.1), [0, 1])


def test_reduce_keys_errors():
    with pytest.raises(ShapeSpaceError) as exc:
        reduce_keys(np.arange(5.0), np.zeros(5), -0.1)
    assert exc.value.code == "range"
    with pytest.raises(ShapeSpaceError) as exc:
        reduce_keys(np.arange(5.0), np.zeros(4), 0.1)
    assert exc.value.code == "shape"
    with pytest.raises(ShapeSpaceError) as exc:
        reduce_keys([], [], 0.1)
    assert exc.value.code == "shape"


def test_reduce_keys_negative_tol_rejected_for_short_curves():
    with pytest.raises(ShapeSpaceError):
        reduce_keys([0.0, 1.0], [0.0, 1.0], -1.0)


# --------------------------------------------------------------------------- procrustes
@pytest.mark.parametrize("seed", [40, 41, 42])
def test_procrustes_recovers_similarity(seed):
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((25, 3))
    R = Rotation.random(random_state=seed).as_matrix()
    s, t = float(rng.uniform(0.3, 3.0)), rng.standard_normal(3) * 4
    Y = s * X @ R.T + t
    s_hat, R_hat, t_hat = procrustes(X, Y)
    assert abs(s_hat - s) <= 1e-10 * s
    np.testing.assert_allclose(R_hat, R, rtol=0, atol=1e-10)
    np.testing.assert_allclose(t_hat, t, rtol=0, atol=1e-10)
    assert np.linalg.det(R_hat) == pytest.approx(1.0, abs=1e-12)


def test_procrustes_coplanar_and_minimal_points():
    rng = np.random.default_rng(43)
    R = Rotation.random(random_state=43).as_matrix()
    for X in (np.column_stack([rng.standard_normal((6, 2)), np.zeros(6)]),     # coplanar
              rng.standard_normal((3, 3))):                                    # 3 points
        Y = 1.5 * X @ R.T + np.array([1.0, -2.0, 0.5])
        s_hat, R_hat, t_hat = procrustes(X, Y)
        assert s_hat == pytest.approx(1.5, rel=1e-10)
        np.testing.assert_allclose(R_hat, R, rtol=0, atol=1e-10)
        np.testing.assert_allclose(t_hat, [1.0, -2.0, 0.5], rtol=0, atol=1e-10)


def test_procrustes_without_scaling():
    rng = np.random.default_rng(44)
    X = rng.standard_normal((10, 3))
    R = Rotation.random(random_state=44).as_matrix()
    Y = X @ R.T + 1.0
    s, R_hat, t = procrustes(X, Y, scaling=False)
    assert s == 1.0
    np.testing.assert_allclose(R_hat, R, rtol=0, atol=1e-10)
    np.testing.assert_allclose(t, np.ones(3), rtol=0, atol=1e-10)


def test_procrustes_reflection_free():
    rng = np.random.default_rng(45)
    X = rng.standard_normal((20, 3)) * np.array([3.0, 2.0, 1.0])
    M = np.diag([1.0, 1.0, -1.0])                        # a mirror: fits exactly, but is not a rotation
    Y = 0.8 * X @ M.T + np.array([0.5, 0.0, -1.0])
    s, R, t = procrustes(X, Y)
    np.testing.assert_allclose(R @ R.T, np.eye(3), rtol=0, atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)
    # reference: the best proper rotation (Kabsch, scipy) on the centred sets; for fixed R the optimal
    # scale is Σ⟨y_i, R x_i⟩ / Σ‖x_i‖² and t = ȳ − s R x̄
    Xc, Yc = X - X.mean(axis=0), Y - Y.mean(axis=0)
    R_ref = Rotation.align_vectors(Yc, Xc)[0].as_matrix()
    s_ref = float(np.sum(Yc * (Xc @ R_ref.T)) / np.sum(Xc ** 2))
    np.testing.assert_allclose(R, R_ref, rtol=0, atol=1e-8)
    assert s == pytest.approx(s_ref, rel=1e-8)
    np.testing.assert_allclose(t, Y.mean(axis=0) - s_ref * R_ref @ X.mean(axis=0), rtol=0, atol=1e-8)
    # the mirror would have fitted better (exactly)
    resid_rot = np.linalg.norm(s * X @ R.T + t - Y)
    assert resid_rot > 1e-3
    assert np.linalg.norm(0.8 * X @ M.T + np.array([0.5, 0.0, -1.0]) - Y) < 1e-12


def test_procrustes_collinear():
    d = np.array([1.0, 2.0, -0.5])
    X = np.outer(np.linspace(-1, 2, 6), d) + np.array([0.3, 0.1, 0.0])
    with pytest.raises(ShapeSpaceError) as exc:
        procrustes(X, X + 1.0)
    assert exc.value.code == "collinear"
    with pytest.raises(ShapeSpaceError) as exc:
        procrustes(np.ones((4, 3)), np.zeros((4, 3)))            # all points coincide
    assert exc.value.code == "collinear"


@pytest.mark.parametrize("m", [0, 1, 2])
def test_procrustes_too_few_points(m):
    rng = np.random.default_rng(46)
    with pytest.raises(ShapeSpaceError) as exc:
        procrustes(rng.standard_normal((m, 3)), rng.standard_normal((m, 3)))
    assert exc.value.code == "too_few"


def test_procrustes_shape_mismatch():
    with pytest.raises(ShapeSpaceError) as exc:
        procrustes(np.zeros((5, 3)), np.zeros((4, 3)))
    assert exc.value.code == "shape"


# --------------------------------------------------------------------------- landmark_warp
def test_landmark_warp_maps_landmarks_exactly():
    rng = np.random.default_rng(50)
    src = rng.standard_normal((9, 3))
    R = Rotation.random(random_state=50).as_matrix()
    dst = 1.3 * src @ R.T + np.array([2.0, 0.0, -1.0]) + 0.2 * rng.standard_normal((9, 3))   # non-rigid
    out = landmark_warp(src, dst, src)
    np.testing.assert_allclose(out, dst, rtol=0, atol=1e-8)


def test_landmark_warp_pure_similarity_everywhere():
    rng = np.random.default_rng(51)
    src = rng.standard_normal((8, 3))
    R = Rotation.random(random_state=51).as_matrix()
    s, t = 0.7, np.array([0.0, 3.0, 1.0])
    dst = s * src @ R.T + t
    pts = rng.uniform(-3, 3, (200, 3))
    np.testing.assert_allclose(landmark_warp(src, dst, pts), s * pts @ R.T + t, rtol=0, atol=1e-8)


def test_landmark_warp_affine_reproduced_everywhere():
    # thin-plate spline with a linear polynomial reproduces any affine map exactly (analytic identity)
    rng = np.random.default_rng(52)
    src = rng.standard_normal((10, 3))
    A = np.eye(3) + 0.3 * rng.standard_normal((3, 3))
    b = rng.standard_normal(3)
    pts = rng.uniform(-2, 2, (100, 3))
    np.testing.assert_allclose(landmark_warp(src, src @ A.T + b, pts), pts @ A.T + b, rtol=0, atol=1e-8)


@pytest.mark.parametrize("m", [1, 2])
def test_landmark_warp_too_few(m):
    rng = np.random.default_rng(53)
    with pytest.raises(ShapeSpaceError) as exc:
        landmark_warp(rng.standard_normal((m, 3)), rng.standard_normal((m, 3)), np.zeros((1, 3)))
    assert exc.value.code == "too_few"


def test_landmark_warp_collinear_is_refused():
    t = np.linspace(0.0, 1.0, 6)[:, None]
    line = np.hstack([t, 2 * t, -t])
    rng = np.random.default_rng(55)
    with pytest.raises(ShapeSpaceError) as exc:
        landmark_warp(line, rng.standard_normal((6, 3)), np.zeros((1, 3)))
    assert exc.value.code == "collinear"


@pytest.mark.parametrize("m", [3, 7])
def test_landmark_warp_coplanar_and_three_landmarks_land_exactly(m):
    rng = np.random.default_rng(56)
    src = np.column_stack([rng.standard_normal((m, 2)), np.zeros(m)])       # all in the plane z = 0
    dst = src @ Rotation.from_rotvec([0.2, -0.1, 0.4]).as_matrix().T * 1.3 + 0.05 * rng.standard_normal((m, 3))
    assert landmark_layout(src) == "coplanar"
    np.testing.assert_allclose(landmark_warp(src, dst, src), dst, rtol=0, atol=1e-9)


def test_peak_landmarks_pick_each_shapes_most_moved_vertex():
    rng = np.random.default_rng(57)
    ds = rng.normal(size=(4, 30, 3)) * 0.01
    dt = rng.normal(size=(5, 40, 3)) * 0.01
    for i, (a, b) in enumerate([(3, 7), (11, 20), (25, 39)]):
        ds[i, a] = [1.0, 0, 0]
        dt[i + 1, b] = [0, 2.0, 0]
    ds[3] = 0.0                                                            # an empty source shape
    src, dst, used = peak_landmarks(ds, dt, [(0, 1), (1, 2), (2, 3), (3, 4)])
    np.testing.assert_array_equal(src, [3, 11, 25])
    np.testing.assert_array_equal(dst, [7, 20, 39])
    assert used == [(0, 1), (1, 2), (2, 3)]


def test_landmark_warp_count_mismatch():
    rng = np.random.default_rng(54)
    with pytest.raises(ShapeSpaceError):
        landmark_warp(rng.standard_normal((5, 3)), rng.standard_normal((6, 3)), np.zeros((1, 3)))


# --------------------------------------------------------------------------- closest_points
def test_closest_points_brute_force():
    rng = np.random.default_rng(60)
    surface = rng.standard_normal((300, 3))
    pts = rng.standard_normal((80, 3)) * 1.5
    idx, dist = closest_points(pts, surface)
    D = np.linalg.norm(pts[:, None, :] - surface[None, :, :], axis=2)
    np.testing.assert_array_equal(idx, np.argmin(D, axis=1))
    np.testing.assert_allclose(dist, D.min(axis=1), rtol=1e-12, atol=1e-14)
    # a point that is a surface vertex maps to itself at distance 0
    idx2, dist2 = closest_points(surface[[7, 123]], surface)
    np.testing.assert_array_equal(idx2, [7, 123])
    np.testing.assert_array_equal(dist2, [0.0, 0.0])


# --------------------------------------------------------------------------- smooth key reduction
def _smooth_noisy_curve(seed, n=240, noise=0.002):
    rng = np.random.default_rng(seed)
    t = np.arange(1.0, n + 1)
    base = np.convolve(rng.normal(size=n + 40), np.hanning(31), "same")[20:n + 20] * 0.08
    return t, base + rng.normal(size=n) * noise


def test_hermite_matches_scipy_cubic_hermite_spline():
    from scipy.interpolate import CubicHermiteSpline
    rng = np.random.default_rng(3)
    kt = np.cumsum(rng.uniform(0.5, 3.0, size=9))
    kv, km = rng.normal(size=9), rng.normal(size=9)
    x = np.linspace(kt[0], kt[-1], 401)
    np.testing.assert_allclose(hermite(kt, kv, km, x), CubicHermiteSpline(kt, kv, km)(x), rtol=0, atol=1e-12)


def test_curve_slopes_exact_on_parabolas():
    t = np.array([0.0, 0.7, 1.1, 2.5, 3.0, 4.2])
    v = 2.0 * t ** 2 - 3.0 * t + 1.0
    m = curve_slopes(t, v)
    np.testing.assert_allclose(m[1:-1], 4.0 * t[1:-1] - 3.0, rtol=0, atol=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_reduce_keys_bezier_stays_within_tolerance(seed):
    t, v = _smooth_noisy_curve(seed)
    for tol in (0.002, 0.01, 0.05):
        idx, kv, km = reduce_keys_bezier(t, v, tol)
        assert idx[0] == 0 and idx[-1] == t.size - 1 and np.all(np.diff(idx) > 0)
        assert np.abs(hermite(t[idx], kv, km, t) - v).max() <= tol


def test_reduce_keys_bezier_stage_one_is_the_optimal_interpolating_subset():
    # Without refinement every key sits on a sample with the data slope, and no valid solution of that
    # family has fewer keys: brute force over all subsets of a short curve.
    t, v = _smooth_noisy_curve(5, n=14, noise=0.003)
    tol = 0.004
    idx, kv, km = reduce_keys_bezier(t, v, tol, refine=False)
    np.testing.assert_array_equal(kv, v[idx])
    m = curve_slopes(t, v)
    np.testing.assert_array_equal(km, m[idx])
    best = None
    for r in range(0, t.size - 1):
        for inner in itertools.combinations(range(1, t.size - 1), r):
            keys = [0, *inner, t.size - 1]
            if np.abs(hermite(t[keys], v[keys], m[keys], t) - v).max() <= tol:
                best = len(keys)
                break
        if best is not None:
            break
    assert idx.size == best


def test_reduce_keys_bezier_beats_linear_on_smooth_curves():
    t, v = _smooth_noisy_curve(7, noise=0.0)
    lin = reduce_keys(t, v, 0.005).size
    idx, _, _ = reduce_keys_bezier(t, v, 0.005)
    assert idx.size < 0.6 * lin


def test_reduce_keys_bezier_refinement_only_removes_keys():
    t, v = _smooth_noisy_curve(8)
    a = reduce_keys_bezier(t, v, 0.01, refine=False)[0]
    b = reduce_keys_bezier(t, v, 0.01)[0]
    assert set(b) <= set(a) and b.size < a.size


def test_reduce_keys_bezier_parabola_needs_two_keys():
    # the three-point slopes are exact on a parabola, which a single cubic Hermite segment reproduces
    t = np.sort(np.random.default_rng(4).uniform(0.0, 5.0, 60))
    v = -0.4 * t ** 2 + t + 0.3
    idx, kv, km = reduce_keys_bezier(t, v, 1e-9)
    assert idx.size == 2
    np.testing.assert_allclose(hermite(t[idx], kv, km, t), v, rtol=0, atol=1e-9)


@pytest.mark.parametrize("times, values, tol, code", [
    ([0.0, 1.0], [0.0], 0.1, "shape"),
    ([], [], 0.1, "shape"),
    ([0.0, 1.0, 2.0], [0.0, 1.0, 0.0], -1.0, "range"),
    ([0.0, 2.0, 1.0], [0.0, 1.0, 0.0], 0.1, "order"),
])
def test_reduce_keys_bezier_bad_input(times, values, tol, code):
    with pytest.raises(ShapeSpaceError) as exc:
        reduce_keys_bezier(times, values, tol)
    assert exc.value.code == code
