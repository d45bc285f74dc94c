"""Bounded space-time at near-unbounded cost (#11): the exact block-tridiagonal route, the peak active set, the
interior point for degenerate (redundant) rigs, progress and cancel.

References are independent: the quadratic objective is rebuilt here from its definition (dense, by evaluation)
and minimised over the box by quadprog (Goldfarb–Idnani), or the operator is formed densely with numpy.
"""
import numpy as np
import pytest

import core.retarget.spacetime_solver as st
from core.progress import Cancelled
from core.result import Status
from core.retarget.perframe import fit_frames
from core.retarget.spacetime_solver import BlockCholesky, SpacetimeSystem, bounded, kernels, run_peaks, spacetime

quadprog = pytest.importorskip("quadprog")


def _take(seed, F=40, n=4, m3=12, duplicate=False):
    """A clipped take: weights swinging beyond [0, 1] on a random rig (optionally with a duplicate key, a scaled
    copy and an empty key: rank n − 2 of n + 3)."""
    rng = np.random.default_rng(seed)
    B = rng.normal(size=(m3, n))
    t = np.linspace(0, 1, F)[:, None]
    W = 0.5 + 0.9 * np.sin(2 * np.pi * rng.uniform(0.5, 2, n) * t + rng.uniform(0, 6, n))
    b0 = rng.normal(size=m3) * 0.1
    S = b0 + W @ B.T + 0.02 * rng.normal(size=(F, m3))
    if duplicate:
        B = np.column_stack([B, B[:, 0], 1.7 * B[:, 1], np.zeros(m3)])
    return B, b0, S


def _dense_qp(B, b0, S, sig, lam, beta, anchor, first, last, lo, hi):
    """The problem rebuilt from its definition and solved over the box by quadprog: interior weights (f − 2, n)."""
    F, n = S.shape[0], B.shape[1]
    N = (F - 2) * n
    W0 = np.zeros((F, n))
    if anchor:                                       # the per-frame ridge fit the anchored regulariser pulls to
        W0 = np.linalg.solve(B.T @ B + lam * np.diag(1.0 / sig ** 2), B.T @ (S - b0).T).T

    def f(x):
        W = np.vstack([first, x.reshape(F - 2, n), last])
        E = W @ B.T - (S - b0)
        return (np.sum(np.diff(E, axis=0) ** 2) + beta * np.sum(E[1:-1] ** 2)
                + lam * np.sum(((W[1:-1] - W0[1:-1]) / sig) ** 2))
    f0, eye = f(np.zeros(N)), np.eye(N)
    fi = np.array([f(eye[i]) for i in range(N)])
    H = np.array([[f(eye[i] + eye[j]) - fi[i] - fi[j] + f0 for j in range(N)] for i in range(N)])
    g = fi - f0 - 0.5 * np.diag(H)
    H = 0.5 * (H + H.T)
    C = np.hstack([np.eye(N), -np.eye(N)])
    bnd = np.concatenate([np.tile(lo, F - 2), -np.tile(hi, F - 2)])
    return quadprog.solve_qp(H, -g, C, bnd)[0].reshape(F - 2, n)


def _relative_lam(B, sig, lam):
    M = sig[:, None] * (B.T @ B) * sig[None, :]
    return lam * np.linalg.eigvalsh(M).clip(0).mean()


@pytest.mark.parametrize("beta, anchor", [(0.0, False), (1e-3, True), (0.5, True)])
def test_peak_active_set_gives_the_independent_qp_minimiser(beta, anchor):
    B, b0, S = _take(1)
    n = B.shape[1]
    sig = np.random.default_rng(2).uniform(0.5, 2.0, n)
    lo, hi = np.zeros(n), np.ones(n)
    res = spacetime(B, b0, S, sig, 1e-2, lo=lo, hi=hi, beta=beta, anchor=anchor)
    assert res.status == Status.OK and res.diagnostics["peak_iterations"] > 0
    assert res.diagnostics["interior_point_iterations"] == 0
    W = res.weights
    ref = _dense_qp(B, b0, S, sig, 1e-2, beta, anchor, W[0], W[-1], lo, hi)
    assert np.sum((ref <= 1e-9) | (ref >= 1 - 1e-9)) > 10                  # the bounds matter
    np.testing.assert_allclose(W[1:-1], ref, rtol=0, atol=1e-7)


def test_interior_point_route_gives_the_independent_qp_minimiser(monkeypatch):
    monkeypatch.setattr(bounded, "PEAK_PATIENCE", 0)                           # hand over at once
    B, b0, S = _take(3)
    n = B.shape[1]
    sig = np.ones(n)
    lo, hi = np.zeros(n), np.ones(n)
    res = spacetime(B, b0, S, sig, 1e-2, lo=lo, hi=hi, anchor=True)
    assert res.status == Status.OK and res.diagnostics["interior_point_iterations"] > 0
    W = res.weights
    ref = _dense_qp(B, b0, S, sig, 1e-2, 0.0, True, W[0], W[-1], lo, hi)
    np.testing.assert_allclose(W[1:-1], ref, rtol=0, atol=1e-7)


def test_redundant_rig_bounded_spacetime_converges_to_the_qp_minimiser_and_splits_duplicates_equally():
    B, b0, S = _take(4, F=30, duplicate=True)
    n = B.shape[1]                                       # 7 keys, rank 4: a duplicate, a scaled copy, an empty key
    assert np.linalg.matrix_rank(B) == 4
    sig = np.ones(n)
    lo, hi = np.zeros(n), np.ones(n)
    lam = 1e-4
    res = spacetime(B, b0, S, sig, lam, lo=lo, hi=hi, relative=True, anchor=True)
    assert res.status == Status.OK
    W = res.weights
    ref = _dense_qp(B, b0, S, sig, _relative_lam(B, sig, lam), 0.0, True, W[0], W[-1], lo, hi)
    np.testing.assert_allclose(W[1:-1], ref, rtol=0, atol=1e-6)
    # the tie-break of the anchored regulariser (min-norm per-frame ridge): exact duplicates share equally,
    # the empty key stays at 0, the scaled copy takes 1.7 times the original's share where neither clips
    np.testing.assert_allclose(W[1:-1, 0], W[1:-1, 4], atol=1e-6)
    assert np.abs(W[1:-1, 6]).max() <= 1e-9
    inside = (W[1:-1, 1] > 1e-6) & (W[1:-1, 5] < 1 - 1e-6) & (W[1:-1, 5] > 1e-6)
    np.testing.assert_allclose(W[1:-1, 5][inside], 1.7 * W[1:-1, 1][inside], atol=1e-5)


def _dense_operator(system):
    N, n = system.shape
    T = 2 * np.eye(N) - np.eye(N, k=1) - np.eye(N, k=-1)
    return np.kron(T + system.beta * np.eye(N), system.M) + system.lam * np.eye(N * n)


def _random_system(rng, rows, n, frames, beta):
    """A random space-time system, its dense operator and a right-hand side."""
    system = SpacetimeSystem(rng.normal(size=(rows, n)), rng.uniform(0.5, 2, n), 1e-3, frames, beta=beta)
    return system, _dense_operator(system), rng.normal(size=system.shape)


def _held_reference(H, r, held):
    """The dense solve of the held system on the free entries (NumPy), held entries 0, flat."""
    free = ~held.ravel()
    want = np.zeros(H.shape[0])
    if free.any():
        want[free] = np.linalg.solve(H[np.ix_(free, free)], r.ravel()[free])
    return want


@pytest.mark.parametrize("keep_bytes", [2 ** 28, 0])          # products kept, or recomputed (long takes)
def test_block_cholesky_solves_the_held_and_shifted_systems(monkeypatch, keep_bytes):
    monkeypatch.setattr(kernels, "BLOCK_KEEP_BYTES", keep_bytes)
    rng = np.random.default_rng(6)
    system, H, r = _random_system(rng, 15, 5, 17, 0.2)
    held = rng.uniform(size=system.shape) < 0.3
    np.testing.assert_allclose(BlockCholesky(system, held).solve(r).ravel(), _held_reference(H, r, held),
                               rtol=1e-9, atol=1e-11)
    later = held.copy()                                             # a change from frame 9 on: blocks 0–8 reused
    later[9:] = rng.uniform(size=later[9:].shape) < 0.3
    reused = BlockCholesky(system, later, previous=BlockCholesky(system, held))
    np.testing.assert_allclose(reused.solve(r).ravel(), _held_reference(H, r, later), rtol=1e-9, atol=1e-11)
    shift = rng.uniform(0, 3, size=system.shape)
    want = np.linalg.solve(H + np.diag(shift.ravel()), r.ravel())
    np.testing.assert_allclose(BlockCholesky(system, shift=shift).solve(r).ravel(), want, rtol=1e-9, atol=1e-11)


@pytest.mark.parametrize("keep_bytes", [2 ** 28, 0])
def test_block_cholesky_factors_only_the_free_entries(monkeypatch, keep_bytes):
    """Frames with every entry held (none free: no block at all), with none held, and mixed, at the ends and in
    runs; a change of held set reusing the frames before it: the dense solve on the free entries (NumPy)."""
    monkeypatch.setattr(kernels, "BLOCK_KEEP_BYTES", keep_bytes)
    system, H, r = _random_system(np.random.default_rng(11), 12, 6, 24, 0.1)
    rng = np.random.default_rng(12)
    held = rng.uniform(size=system.shape) < 0.4
    held[[0, 5, 6, 7, 13, -1]] = True                              # nothing free
    held[[2, 9, 10]] = False                                        # everything free
    for case in (held, ~held, np.zeros_like(held), np.ones_like(held)):
        got = BlockCholesky(system, case).solve(r)
        np.testing.assert_allclose(got.ravel(), _held_reference(H, r, case), rtol=1e-9, atol=1e-11)
        assert np.all(got[case] == 0.0)
    later = held.copy()
    later[8:, :3] = ~later[8:, :3]
    reused = BlockCholesky(system, later, previous=BlockCholesky(system, held))
    np.testing.assert_allclose(reused.solve(r).ravel(), _held_reference(H, r, later), rtol=1e-9, atol=1e-11)


def test_run_peaks_marks_the_deepest_entry_of_every_run_per_channel():
    v = np.array([[0.0, 1.0], [0.2, 2.0], [0.5, 0.0], [0.1, 3.0], [0.0, 3.5], [0.3, 0.0]])
    want = np.zeros_like(v, dtype=bool)
    want[[2, 5], 0] = True
    want[[1, 4], 1] = True
    np.testing.assert_array_equal(run_peaks(v), want)
    assert not run_peaks(np.zeros((4, 3))).any()


def test_run_peaks_with_a_fraction_marks_each_run_s_entries_at_least_that_deep():
    v = np.array([[0.0, 1.0], [0.2, 2.0], [0.5, 0.0], [0.1, 3.0], [0.0, 3.5], [0.3, 0.0]])
    want = np.zeros_like(v, dtype=bool)
    want[[2, 5], 0] = True                              # runs [0.2, 0.5] and [0.3]: 0.2 < 0.25
    want[[0, 1, 3, 4], 1] = True                        # runs [1, 2] and [3, 3.5]: all at least half
    np.testing.assert_array_equal(run_peaks(v, 0.5), want)
    np.testing.assert_array_equal(run_peaks(v, 1.0), run_peaks(v))
    assert run_peaks(v, 1e-9).sum() == np.count_nonzero(v)


def test_a_long_clipped_take_needs_few_exact_solves():
    # the cost of the bounded solve is its number of exact reduced solves: a handful, not one per active entry
    B, b0, S = _take(7, F=600, n=8, m3=30)
    n = B.shape[1]
    res = spacetime(B, b0, S, np.full(n, 0.3), 1e-6, lo=np.zeros(n), hi=np.ones(n), relative=True, anchor=True)
    assert res.status == Status.OK
    assert res.iterations == res.diagnostics["peak_iterations"] <= 15
    W = res.weights
    assert W.min() >= 0 and W.max() <= 1 and np.mean((W <= 0) | (W >= 1)) > 0.02


@pytest.mark.parametrize("bounded", [False, True])
def test_spacetime_reports_progress_and_can_be_cancelled(bounded):
    B, b0, S = _take(8, F=60)
    n = B.shape[1]
    kw = {"lo": np.zeros(n), "hi": np.ones(n)} if bounded else {}
    seen = []
    res = spacetime(B, b0, S, np.ones(n), 1e-3, progress=seen.append, **kw)
    assert res.converged and seen and seen[-1] == 1.0
    assert all(0.0 <= a <= b <= 1.0 for a, b in zip(seen, seen[1:]))

    def cancel(fraction):
        if fraction > 0.3:
            raise Cancelled()
    with pytest.raises(Cancelled):
        spacetime(B, b0, S, np.ones(n), 1e-3, progress=cancel, **kw)


def test_perframe_reports_progress_and_can_be_cancelled():
    B, b0, S = _take(9, F=300)
    n = B.shape[1]
    seen = []
    fit_frames(B, b0, S, np.zeros(n), np.ones(n), progress=seen.append)
    assert len(seen) >= 300 // 64 and seen[-1] == 1.0 and seen == sorted(seen)

    def cancel(fraction):
        if fraction > 0.5:
            raise Cancelled()
    with pytest.raises(Cancelled):
        fit_frames(B, b0, S, np.zeros(n), np.ones(n), progress=cancel)


def test_dense_active_set_settles_the_face_like_quadprog():
    # the per-frame fit's finish when the projected Newton's ε-active set flips between two faces
    from core.boxqp import _pdas_dense
    rng = np.random.default_rng(10)
    for _ in range(5):
        n = 12
        U = np.linalg.qr(rng.normal(size=(n, n)))[0]
        H = U @ np.diag(np.geomspace(10.0, 0.1, n)) @ U.T
        g = H @ rng.uniform(-0.5, 1.5, n)
        lo, hi = np.zeros(n), np.ones(n)
        ref = quadprog.solve_qp(H, g, np.hstack([np.eye(n), -np.eye(n)]), np.concatenate([lo, -hi]))[0]
        x, _ = _pdas_dense(H, g, lo, hi, np.clip(g, lo, hi), np.zeros(n, bool), np.zeros(n, bool))
        assert x is not None
        np.testing.assert_allclose(x, ref, atol=1e-7)


@pytest.mark.parametrize("patience", [5, 0])                       # peak active set, or interior point at once
def test_one_sided_bounds_give_the_independent_qp_minimiser(monkeypatch, patience):
    monkeypatch.setattr(bounded, "PEAK_PATIENCE", patience)
    B, b0, S = _take(11, F=30)
    n = B.shape[1]
    sig = np.ones(n)
    res = spacetime(B, b0, S, sig, 1e-2, lo=0.0, anchor=True)
    assert res.status == Status.OK
    W = res.weights
    ref = _dense_qp(B, b0, S, sig, 1e-2, 0.0, True, W[0], W[-1], np.zeros(n), np.full(n, 1e6))  # 1e6: never binds
    assert np.sum(ref <= 1e-9) > 5 and ref.max() < 1e5
    np.testing.assert_allclose(W[1:-1], ref, rtol=0, atol=1e-7)


def test_single_threaded_restores_the_blas_thread_counts():
    from core import blas_threads
    before = [int(get()) for _, get in (blas_threads._controls or blas_threads._find())]
    with blas_threads.single_threaded():
        inside = [int(get()) for _, get in blas_threads._controls]
        np.linalg.cholesky(np.eye(200) * 2.0)
    after = [int(get()) for _, get in blas_threads._controls]
    assert all(c == 1 for c in inside) and after == before


def test_slivers_below_zero_are_settled_by_one_solve_with_every_violation_held():
    """A take with nothing to clip whose unbounded solution still dips a sliver below 0 where the source rests
    at 0 (as on a 36,000-frame take onto ICT FaceKit): one exact solve with every violated entry held meets the
    KKT test; the answer is the box-QP minimiser (quadprog on the explicit problem) to the tolerance's order."""
    rng = np.random.default_rng(41)
    F, n, m3 = 36, 4, 12
    B = rng.normal(size=(m3, n))
    t = np.linspace(0, 1, F)[:, None]
    W = np.clip(np.sin(2 * np.pi * rng.uniform(0.5, 1.5, n) * t + rng.uniform(0, 6, n)), 0.0, None) * 0.6
    S = W @ B.T + 1e-9 * rng.normal(size=(F, m3))     # rests at exactly 0 for stretches; a whisper of noise
    sig = np.full(n, 0.3)
    lo, hi = np.zeros(n), np.ones(n)
    system = SpacetimeSystem(B, sig, 1e-7, F, relative=True)       # the retarget command's λ
    ends = W[[0, -1]]
    Y = system.solve(system.rhs(S, np.zeros(m3), ends[0], ends[1], anchor=True))
    ylo, yhi = np.broadcast_to(lo / sig, Y.shape), np.broadcast_to(hi / sig, Y.shape)
    assert st.shallow_violation(Y, ylo, yhi)                  # slivers only: the case this route is for
    assert np.sum(Y < ylo) >= 10
    res = spacetime(B, np.zeros(m3), S, sig, 1e-7, first=ends[0], last=ends[1], lo=lo, hi=hi, relative=True,
                    anchor=True)
    assert res.status == Status.OK
    assert res.diagnostics["clipped_solve"] and res.diagnostics["solves"] == 1
    assert res.diagnostics["peak_iterations"] == 0 and res.diagnostics["interior_point_iterations"] == 0
    want = _dense_qp(B, np.zeros(m3), S, sig, _relative_lam(B, sig, 1e-7), 0.0, True, ends[0], ends[1], lo, hi)
    np.testing.assert_allclose(res.weights[1:-1], want, rtol=0, atol=1e-7)
    assert res.weights.min() >= 0.0 and res.weights.max() <= 1.0


def test_deep_clipping_does_not_take_the_sliver_route():
    B, b0, S = _take(5)
    res = spacetime(B, b0, S, np.ones(B.shape[1]), 1e-3, lo=0.0, hi=1.0, relative=True, anchor=True)
    assert res.status == Status.OK and not res.diagnostics["clipped_solve"]
