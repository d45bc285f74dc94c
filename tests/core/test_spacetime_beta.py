"""Space-time with the position term β‖W Bᵀ − S‖² (#11): the decoupled solve against a dense reference."""
import numpy as np
import pytest

from core.result import ShapeSpaceError, Status
from core.retarget.spacetime_solver import spacetime


def _problem(seed, F=12, n=4, m3=9):
    rng = np.random.default_rng(seed)
    B = rng.normal(size=(m3, n))
    b0 = rng.normal(size=m3) * 0.1
    S = b0 + np.cumsum(rng.normal(size=(F, m3)) * 0.3, axis=0)
    return B, b0, S, rng.uniform(0.5, 2.0, n)


def _dense_objective(W, B, b0, S, sig, lam, beta):
    E = W @ B.T - (S - b0)
    return (np.sum(np.diff(E, axis=0) ** 2) + beta * np.sum(E[1:-1] ** 2)
            + lam * np.sum((W[1:-1] / sig) ** 2))


def _dense_solve(B, b0, S, sig, lam, beta, first, last):
    F, n = S.shape[0], B.shape[1]
    N = (F - 2) * n
    # the objective is quadratic in the interior weights: recover H and g from evaluations
    def f(x):
        W = np.vstack([first, x.reshape(F - 2, n), last])
        return _dense_objective(W, B, b0, S, sig, lam, beta)
    f0, I = f(np.zeros(N)), np.eye(N)
    H = np.array([[f(I[i] + I[j]) - f(I[i]) - f(I[j]) + f0 for j in range(N)] for i in range(N)])
    g = np.array([f(I[i]) - f0 for i in range(N)]) - 0.5 * np.diag(H)
    return np.linalg.solve(H, -g).reshape(F - 2, n)


@pytest.mark.parametrize("beta", [0.0, 1e-3, 0.5])
def test_spacetime_with_beta_matches_the_dense_minimiser(beta):
    B, b0, S, sig = _problem(1)
    res = spacetime(B, b0, S, sig, 1e-2, beta=beta)
    W = res.weights
    ref = _dense_solve(B, b0, S, sig, 1e-2, beta, W[0], W[-1])
    np.testing.assert_allclose(W[1:-1], ref, rtol=0, atol=1e-8)


@pytest.mark.parametrize("beta", [1e-3, 0.5])
def test_bounded_spacetime_with_beta_satisfies_kkt(beta):
    B, b0, S, sig = _problem(2, F=40)
    res = spacetime(B, b0, S, sig, 1e-2, lo=-0.3, hi=0.3, beta=beta)
    assert res.status == Status.OK
    W = res.weights
    assert W.min() >= -0.3 and W.max() <= 0.3
    # no feasible coordinate move lowers the objective (first-order KKT by finite differences)
    base = _dense_objective(W, B, b0, S, sig, 1e-2, beta)
    for t in range(1, W.shape[0] - 1):
        for k in range(W.shape[1]):
            for step in (1e-5, -1e-5):
                V = W.copy()
                V[t, k] = np.clip(V[t, k] + step, -0.3, 0.3)
                assert _dense_objective(V, B, b0, S, sig, 1e-2, beta) >= base - 1e-9


def test_position_term_reduces_drift_on_a_long_take():
    rng = np.random.default_rng(0)
    n, F = 6, 1640
    B = rng.normal(size=(30, n)) * np.geomspace(1.0, 0.05, n)
    S = np.cumsum(rng.normal(size=(F, n)) * 0.02, axis=0) @ B.T
    err = [np.abs(spacetime(B, np.zeros(30), S, np.ones(n), 1e-3, relative=True, beta=b).weights @ B.T - S).max()
           for b in (0.0, 0.05)]
    assert err[1] < 0.5 * err[0]


def test_negative_beta_is_refused():
    B, b0, S, sig = _problem(3)
    with pytest.raises(ShapeSpaceError) as exc:
        spacetime(B, b0, S, sig, 1e-2, beta=-1.0)
    assert exc.value.code == "range"


def _ridge(B, b0, S, sig, lam):
    """Per-frame ridge fit W⁰ = argmin ‖W Bᵀ − S‖² + λ ‖W Σ⁻¹‖², frame by frame (f, n)."""
    return np.linalg.solve(B.T @ B + lam * np.diag(1.0 / sig ** 2), B.T @ (S - b0).T).T


def test_anchored_spacetime_matches_the_dense_minimiser():
    B, b0, S, sig = _problem(4)
    lam = 1e-2
    W = spacetime(B, b0, S, sig, lam, anchor=True).weights
    W0 = _ridge(B, b0, S, sig, lam)
    F, n = S.shape[0], B.shape[1]

    def f(x):
        V = np.vstack([W[0], x.reshape(F - 2, n), W[-1]])
        E = V @ B.T - (S - b0)
        return np.sum(np.diff(E, axis=0) ** 2) + lam * np.sum(((V[1:-1] - W0[1:-1]) / sig) ** 2)
    x = W[1:-1].ravel()
    grad = np.array([(f(x + e) - f(x - e)) / 2e-6 for e in np.eye(x.size) * 1e-6])
    assert np.abs(grad).max() < 1e-6


def test_anchored_spacetime_does_not_drift_on_a_long_unclipped_take():
    # weak modes (μ_j ≲ λ f²) drift towards zero under the thesis regulariser; anchored, the take stays exact
    rng = np.random.default_rng(0)
    n, F = 30, 1640
    B = rng.normal(size=(300, n)) * np.geomspace(1.0, 1e-2, n)
    S = np.cumsum(rng.normal(size=(F, n)) * 0.02, axis=0) @ B.T
    b0 = np.zeros(300)
    head = np.linalg.norm(np.ptp(S.reshape(F, 100, 3), axis=(0, 1)))
    perframe = _ridge(B, b0, S, np.ones(n), 1e-7 * np.linalg.eigvalsh(B.T @ B).mean())
    pf_err = np.sqrt(np.mean((perframe @ B.T - S) ** 2))
    old = spacetime(B, b0, S, np.ones(n), 1e-7, relative=True).weights
    W = spacetime(B, b0, S, np.ones(n), 1e-7, relative=True, anchor=True).weights
    drift = np.abs(W @ B.T - S).reshape(F, 100, 3)
    assert np.linalg.norm(drift, axis=2).max() <= 1e-3 * head
    assert np.abs(old @ B.T - S).max() > 10 * drift.max()            # the thesis energy does drift here
    assert np.sqrt(np.mean((W @ B.T - S) ** 2)) <= max(2 * pf_err, 1e-6 * head)


def test_anchored_bounded_spacetime_converges():
    B, b0, S, sig = _problem(5, F=60)
    res = spacetime(B, b0, S, sig, 1e-2, lo=-0.3, hi=0.3, anchor=True)
    assert res.status == Status.OK and res.weights.min() >= -0.3 and res.weights.max() <= 0.3
