"""The cloning-matrix route onto a rig's controls (core/rig/cloning.py).

References: on a rig linear in its controls whose expressions lie in its span, the cloning matrix is the exact
least-squares map (``numpy.linalg.lstsq``) and the take is the per-frame solve; on a nonlinear rig the refinement
only lowers each frame's distance (checked by evaluating the rig at the answer)."""
import numpy as np

from core.result import Status
from core.rig.cloning import clone_controls, expression_controls, solve_take_cloning


def _linear(seed=0, n=4, k=6, p=10, F=20):
    rng = np.random.default_rng(seed)
    B = rng.normal(size=(3 * p, n))
    b0 = rng.normal(size=3 * p)
    M = rng.normal(size=(n, k)) * 0.3
    keys = (b0[:, None] + B @ M).T.reshape(k, p, 3)                 # each expression at weight 1
    W = np.abs(rng.normal(size=(F, k))) * 0.4
    return B, b0, M, keys, W


def test_linear_rig_cloning_matrix_is_the_least_squares_map():
    B, b0, M, keys, W = _linear()
    ev = lambda c: (b0 + B @ c).reshape(-1, 3)                       # noqa: E731
    mat = expression_controls(ev, np.zeros(B.shape[1]), keys, reg=0.0, pin_tol=1e-9)
    ref = np.linalg.lstsq(B, keys.reshape(len(keys), -1).T - b0[:, None], rcond=None)[0].T
    assert mat.status == Status.OK
    np.testing.assert_allclose(mat.matrix, ref, atol=1e-8)
    np.testing.assert_allclose(clone_controls(mat, W), W @ M.T, atol=1e-8)


def test_linear_rig_take_needs_no_refinement():
    B, b0, M, keys, W = _linear(1)
    ev = lambda c: (b0 + B @ c).reshape(-1, 3)                       # noqa: E731
    T = (b0 + W @ M.T @ B.T).reshape(len(W), -1, 3)
    res = solve_take_cloning(ev, np.zeros(B.shape[1]), keys, W, T, reg=0.0, pin_tol=1e-9, refine_steps=2)
    assert res.status == Status.OK, res.message
    np.testing.assert_allclose(res.value, W @ M.T, atol=1e-8)
    np.testing.assert_allclose(res.diagnostics["cloned"], W @ M.T, atol=1e-8)


def test_nonlinear_rig_refinement_lowers_every_frame():
    rng = np.random.default_rng(4)
    n, k, p, F = 3, 5, 8, 15
    B = rng.normal(size=(3 * p, n))
    ev = lambda c: (B @ np.tanh(c) + 0.3 * B @ c ** 2).reshape(-1, 3)   # noqa: E731
    keys = np.stack([ev(c) for c in rng.normal(size=(k, n)) * 0.4])
    W = np.abs(rng.normal(size=(F, k))) * 0.3
    T = np.stack([ev(c) for c in W @ rng.normal(size=(k, n)) * 0.4])
    lo, hi = np.full(n, -1.0), np.full(n, 1.0)
    res = solve_take_cloning(ev, np.zeros(n), keys, W, T, lo=lo, hi=hi, reg=1e-8, refine_steps=4)
    before = np.array([np.sqrt(np.mean(np.sum((ev(c) - t) ** 2, -1))) for c, t in zip(res.diagnostics["cloned"], T)])
    after = np.array([np.sqrt(np.mean(np.sum((ev(c) - t) ** 2, -1))) for c, t in zip(res.value, T)])
    np.testing.assert_allclose(after, res.rms, atol=1e-12)
    assert np.all(after <= before + 1e-12) and after.mean() < 0.5 * before.mean()
    assert np.all((res.value >= lo) & (res.value <= hi))
    assert res.status in (Status.OK, Status.NOT_CONVERGED)
    if res.status == Status.NOT_CONVERGED:
        assert "did not converge" in res.message
