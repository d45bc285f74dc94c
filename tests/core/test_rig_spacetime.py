"""Space-time retarget onto a rig's controls (core/rig/spacetime.py) against the shape-key space-time solver."""
import numpy as np
import pytest

from core.result import Status
from core.retarget.spacetime_solver import spacetime
from core.rig.spacetime import bounded_block_qp, solve_take_spacetime
from core.rig.take import solve_take


def _linear(seed=0, F=30, n=5, p=12):
    rng = np.random.default_rng(seed)
    B = rng.normal(size=(3 * p, n))
    b0 = rng.normal(size=3 * p)
    W = np.cumsum(rng.normal(size=(F, n)) * 0.15, axis=0)
    S = b0 + W @ B.T + rng.normal(size=(F, 3 * p)) * 0.05
    return B, b0, S, W


def _per_frame(B, b0, S, lo=None, hi=None):
    F, n = S.shape[0], B.shape[1]
    ev = lambda c: (b0 + B @ c).reshape(-1, 3)                      # noqa: E731
    jac = lambda c, p: B                                            # noqa: E731
    res = solve_take(ev, np.zeros(n), S.reshape(F, -1, 3), lo=lo, hi=hi, jacobian=jac, steps=np.full(n, 1e-3),
                     reg=0.0, keep_linearisation=True)
    return ev, res


@pytest.mark.parametrize("bounded", [False, True])
def test_linear_rig_equals_shape_key_spacetime(bounded):
    B, b0, S, W = _linear()
    n = B.shape[1]
    lo, hi = (np.full(n, -0.4), np.full(n, 0.6)) if bounded else (None, None)
    ev, pf = _per_frame(B, b0, S, lo, hi)
    sigma = np.linspace(0.2, 0.5, n)
    lam = 1e-3
    ref = spacetime(B, b0, S, sigma, lam, first=pf.value[0], last=pf.value[-1], lo=lo, hi=hi, relative=True,
                    anchor=True, tol=1e-12)
    got = solve_take_spacetime(ev, pf.value, pf.diagnostics["points"], pf.diagnostics["jacobians"],
                               S.reshape(len(S), -1, 3), sigma, lo=lo, hi=hi, lam=lam)
    assert got.status == Status.OK, got.message
    np.testing.assert_allclose(got.value, ref.weights, atol=1e-7)
    if bounded:
        assert (np.isclose(got.value, -0.4) | np.isclose(got.value, 0.6)).any()    # bounds really active


def test_bounded_block_qp_matches_scipy():
    from scipy.optimize import lsq_linear
    rng = np.random.default_rng(3)
    N, n = 6, 3
    A = rng.normal(size=(N * n + 4, N * n))
    H = np.zeros((N * n, N * n))
    for t in range(N):                                                  # a block-tridiagonal SPD matrix
        for u in (t, t + 1):
            if u < N:
                blk = A[:, t * n:(t + 1) * n].T @ A[:, u * n:(u + 1) * n] * (1.0 if u == t else 0.3)
                H[t * n:(t + 1) * n, u * n:(u + 1) * n] = blk
                H[u * n:(u + 1) * n, t * n:(t + 1) * n] = blk.T
    H += np.eye(N * n) * (1e-3 + max(0.0, -np.linalg.eigvalsh(H).min()))
    g = rng.normal(size=N * n) * 5
    lo, hi = np.full(N * n, -0.2), np.full(N * n, 0.3)
    Dg = np.stack([H[t * n:(t + 1) * n, t * n:(t + 1) * n] for t in range(N)])
    E = np.stack([H[t * n:(t + 1) * n, (t + 1) * n:(t + 2) * n] for t in range(N - 1)])
    x, _, ok = bounded_block_qp(Dg, E, g.reshape(N, n), lo.reshape(N, n), hi.reshape(N, n))
    R = np.linalg.cholesky(H).T                                          # ½xᵀHx + gᵀx = ½‖Rx + R⁻ᵀg‖² + c
    ref = lsq_linear(R, -np.linalg.solve(R.T, g), bounds=(lo, hi), tol=1e-14, method="bvls").x
    assert ok
    np.testing.assert_allclose(x.reshape(-1), ref, atol=1e-8)


def test_nonlinear_rig_decreases_verified_objective():
    rng = np.random.default_rng(5)
    n, p, F = 3, 8, 25
    B = rng.normal(size=(3 * p, n))
    Q = rng.normal(size=(3 * p, n)) * 0.3
    ev = lambda c: (B @ c + Q @ np.sin(2 * c) + 0.2 * (B @ c) ** 2).reshape(-1, 3)   # noqa: E731
    C = np.cumsum(rng.normal(size=(F, n)) * 0.1, axis=0)
    T = np.stack([ev(c) for c in C]) + rng.normal(size=(F, p, 3)) * 0.02
    pf = solve_take(ev, np.zeros(n), T, reg=0.0, keep_linearisation=True)
    got = solve_take_spacetime(ev, pf.value, pf.diagnostics["points"], pf.diagnostics["jacobians"], T,
                               np.full(n, 0.2), lam=1e-4, max_outer=30)
    d = got.diagnostics
    assert d["objective"] <= d["objective_start"]
    # the objective is what the rig evaluates at the answer
    P = np.stack([ev(c) for c in got.value]).reshape(F, -1)
    np.testing.assert_allclose(d["points"].reshape(F, -1), P, atol=1e-12)
    assert got.status in (Status.OK, Status.NOT_CONVERGED)


def test_not_converged_is_reported():
    rng = np.random.default_rng(6)
    n, p, F = 2, 5, 12
    B = rng.normal(size=(3 * p, n))
    ev = lambda c: (B @ np.sin(3 * c)).reshape(-1, 3)            # noqa: E731
    T = np.stack([ev(c) for c in rng.normal(size=(F, n))])
    pf = solve_take(ev, np.zeros(n), T, reg=0.0, keep_linearisation=True, max_iter=2)
    got = solve_take_spacetime(ev, pf.value, pf.diagnostics["points"], pf.diagnostics["jacobians"], T,
                               np.ones(n), lam=1e-6, max_outer=1, ftol=0.0)
    assert got.status == Status.NOT_CONVERGED and "stopped after 1" in got.message
