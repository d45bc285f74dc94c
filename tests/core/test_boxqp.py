"""solve_box_qp (and solve_box_lsq_dual) against independent QP solvers (OSQP, quadprog), KKT conditions
and analytic cases.

Problem: min ½ xᵀ H x − gᵀ x  s.t. lo ≤ x ≤ hi,  H = a I + V diag(s) Vᵀ (positive definite).
Every reference here builds the dense H itself and never calls into core.boxqp.
"""
import numpy as np
import pytest
import scipy.sparse as sp

from core.boxqp import solve_box_lsq_dual, solve_box_qp
from core.result import ShapeSpaceError, Status


# --------------------------------------------------------------------------- helpers
def dense_hessian(a, V, s):
    return a * np.eye(V.shape[0]) + (V * s) @ V.T


def quad_obj(H, g, x):
    return float(0.5 * x @ H @ x - g @ x)


def osqp_box(H, g, lo, hi):
    """OSQP with eps 1e-10 and polishing; asserts the reference itself succeeded and polished."""
    osqp = pytest.importorskip("osqp")  # the independent reference: skipped where not installed
    n = H.shape[0]
    solver = osqp.OSQP()
    solver.setup(sp.triu(sp.csc_matrix(H), format="csc"), -g, sp.identity(n, format="csc"), lo, hi,
                 eps_abs=1e-10, eps_rel=1e-10, polishing=True, max_iter=200000, verbose=False)
    res = solver.solve(raise_error=False)
    assert res.info.status == "solved", res.info.status
    # 1: polished (exact on the identified active set); 2: not needed (no bound active)
    assert res.info.status_polish in (1, 2), "OSQP reference did not polish: not an exact reference"
    return np.asarray(res.x)


def quadprog_box(H, g, lo, hi):
    """Goldfarb–Idnani dual active set: C^T x >= b with rows x >= lo and -x >= -hi (finite bounds only)."""
    quadprog = pytest.importorskip("quadprog")  # the independent reference: skipped where not installed
    n = H.shape[0]
    cols, b = [], []
    fin_lo, fin_hi = np.isfinite(lo), np.isfinite(hi)
    eye = np.eye(n)
    if fin_lo.any():
        cols.append(eye[:, fin_lo])
        b.append(lo[fin_lo])
    if fin_hi.any():
        cols.append(-eye[:, fin_hi])
        b.append(-hi[fin_hi])
    C = np.hstack(cols)
    x = quadprog.solve_qp(H, g, C, np.concatenate(b), 0)[0]
    return x


def kkt_violation(H, g, lo, hi, x, bound_tol=0.0):
    """Largest violation of the box KKT conditions at x (gradient ∇ = Hx − g).

    ``bound_tol`` only decides which variables count as "at a bound" (for points produced by another
    solver, which land within rounding of a bound instead of on it); the KKT tolerance is the caller's.
    """
    grad = H @ x - g
    with np.errstate(invalid="ignore"):
        at_lo = x <= lo + bound_tol * (1 + np.abs(lo))
        at_hi = x >= hi - bound_tol * (1 + np.abs(hi))
    free = ~(at_lo | at_hi)
    viol = [0.0]
    viol.append(float(np.max(np.maximum(lo - x, 0.0), initial=0.0)))      # feasibility
    viol.append(float(np.max(np.maximum(x - hi, 0.0), initial=0.0)))
    viol.append(float(np.max(np.abs(grad[free]), initial=0.0)))             # stationary on free vars
    only_lo = at_lo & ~at_hi
    only_hi = at_hi & ~at_lo
    viol.append(float(np.max(np.maximum(-grad[only_lo], 0.0), initial=0.0)))  # ∇ ≥ 0 at lower bound
    viol.append(float(np.max(np.maximum(grad[only_hi], 0.0), initial=0.0)))   # ∇ ≤ 0 at upper bound
    return max(viol), free, only_lo, only_hi


def random_problem(seed, n, r, negative=False):
    rng = np.random.default_rng(seed)
    a = float(rng.uniform(0.2, 1.5))
    if negative:
        # Orthonormal-ish V is not required: draw V, draw s with some negative entries, then make sure
        # H stays PD by bounding each negative weight against a/‖V‖².
        V = rng.normal(size=(n, r)) / np.sqrt(n)
        s = rng.uniform(0.5, 5.0, size=r)
        neg = rng.random(r) < 0.4
        neg[0] = True
        vmax = np.linalg.norm(V, 2) ** 2
        s[neg] = -rng.uniform(0.05, 0.6, size=neg.sum()) * a / (vmax * max(1, neg.sum()))
    else:
        V = rng.normal(size=(n, r))
        s = rng.uniform(0.1, 3.0, size=r)
    # unconstrained optimum x_u ~ N(0, 1): well outside the box for many coordinates
    x_u = rng.normal(size=n)
    g = a * x_u + V @ (s * (V.T @ x_u))
    lo = -rng.uniform(0.05, 1.0, size=n)
    hi = rng.uniform(0.05, 1.0, size=n)
    return a, V, s, g, lo, hi


CASES = [(n, r) for n in (5, 50, 300) for r in (1, 10, 60)]


# --------------------------------------------------------------------------- agreement with OSQP / quadprog
@pytest.mark.parametrize("negative", [False, True], ids=["s_pos", "s_mixed"])
@pytest.mark.parametrize("n,r", CASES)
def test_matches_osqp_and_quadprog(n, r, negative):
    seed = 1000 * n + 7 * r + (1 if negative else 0)
    a, V, s, g, lo, hi = random_problem(seed, n, r, negative)
    H = dense_hessian(a, V, s)
    eig = np.linalg.eigvalsh(H)
    assert eig.min() > 0, "test construction: H must be positive definite"
    if negative:
        assert np.any(s < 0)

    res = solve_box_qp(a, V, s, g, lo, hi)
    assert res.status == Status.OK, res.message
    x = res.x
    x_osqp = osqp_box(H, g, lo, hi)
    x_qp = quadprog_box(H, g, lo, hi)

    f = quad_obj(H, g, x)
    for x_ref in (x_osqp, x_qp):
        f_ref = quad_obj(H, g, np.clip(x_ref, lo, hi))
        assert abs(f - f_ref) <= 1e-9 * abs(f_ref), (f, f_ref)
        np.testing.assert_allclose(x, x_ref, rtol=0, atol=1e-6)

    # the box really matters in these problems (otherwise this is just a linear solve)
    x_unc = np.linalg.solve(H, g)
    assert np.any((x_unc < lo) | (x_unc > hi))


@pytest.mark.parametrize("negative", [False, True], ids=["s_pos", "s_mixed"])
@pytest.mark.parametrize("n,r", CASES)
def test_kkt_conditions(n, r, negative):
    a, V, s, g, lo, hi = random_problem(50 + n + r, n, r, negative)
    H = dense_hessian(a, V, s)
    assert np.linalg.eigvalsh(H).min() > 0
    res = solve_box_qp(a, V, s, g, lo, hi)
    viol, free, at_lo, at_hi = kkt_violation(H, g, lo, hi, res.x)
    assert viol <= 1e-8, viol
    # a mix of free and bound variables, so each condition was actually exercised on larger problems
    if n >= 50:
        assert free.any() and (at_lo.any() or at_hi.any())


def test_iteration_limit_reports_status():
    a, V, s, g, lo, hi = random_problem(3, 300, 60)
    res = solve_box_qp(a, V, s, g, lo, hi, max_iter=1)
    H = dense_hessian(a, V, s)
    viol = kkt_violation(H, g, lo, hi, res.x)[0]
    # one projected-Newton step cannot be exact here; the result must say so
    assert viol > 1e-8
    assert res.status == Status.NOT_CONVERGED and res.iterations == 1


# --------------------------------------------------------------------------- unconstrained and fixed variables
@pytest.mark.parametrize("n,r", [(5, 1), (50, 10), (300, 60)])
def test_infinite_bounds_give_unconstrained_solution(n, r):
    a, V, s, g, _, _ = random_problem(11 + n, n, r)
    H = dense_hessian(a, V, s)
    res = solve_box_qp(a, V, s, g, np.full(n, -np.inf), np.full(n, np.inf))
    x_ref = np.linalg.solve(H, g)
    assert res.status == Status.OK
    np.testing.assert_allclose(res.x, x_ref, rtol=1e-10, atol=1e-10 * np.abs(x_ref).max())


def test_half_infinite_bounds_match_quadprog():
    n, r = 40, 8
    a, V, s, g, lo, hi = random_problem(21, n, r)
    hi[::2] = np.inf
    lo[1::3] = -np.inf
    H = dense_hessian(a, V, s)
    res = solve_box_qp(a, V, s, g, lo, hi)
    x_qp = quadprog_box(H, g, lo, hi)
    np.testing.assert_allclose(res.x, x_qp, atol=1e-8)
    assert kkt_violation(H, g, lo, hi, res.x)[0] <= 1e-8


def test_equal_bounds_fix_variables():
    n, r = 30, 6
    a, V, s, g, lo, hi = random_problem(31, n, r)
    fixed = np.zeros(n, bool)
    fixed[[0, 3, 4, 17, 29]] = True
    val = np.array([0.3, -0.2, 0.0, 0.9, -0.7])
    lo[fixed] = hi[fixed] = val
    res = solve_box_qp(a, V, s, g, lo, hi)
    np.testing.assert_array_equal(res.x[fixed], val)
    # the free variables solve the reduced QP: H_ff x_f − (g_f − H_fF x_F)
    H = dense_hessian(a, V, s)
    free = ~fixed
    Hff = H[np.ix_(free, free)]
    gf = g[free] - H[np.ix_(free, fixed)] @ val
    x_ref = quadprog_box(Hff, gf, lo[free], hi[free])
    np.testing.assert_allclose(res.x[free], x_ref, atol=1e-8)


def test_all_variables_fixed():
    n = 6
    a, V, s, g, lo, hi = random_problem(41, n, 2)
    lo = hi = np.linspace(-0.5, 0.5, n)
    res = solve_box_qp(a, V, s, g, lo, hi)
    np.testing.assert_array_equal(res.x, lo)
    assert res.status == Status.OK


def test_interior_optimum_is_linear_solve():
    # bounds wide enough that the unconstrained optimum is inside: answer is H⁻¹ g
    n, r = 50, 10
    a, V, s, g, _, _ = random_problem(51, n, r)
    H = dense_hessian(a, V, s)
    x_ref = np.linalg.solve(H, g)
    lo = x_ref - 1.0
    hi = x_ref + 1.0
    res = solve_box_qp(a, V, s, g, lo, hi)
    np.testing.assert_allclose(res.x, x_ref, atol=1e-10 * max(1, np.abs(x_ref).max()))


# --------------------------------------------------------------------------- warm and cold starts
@pytest.mark.parametrize("n,r", [(5, 1), (50, 10), (300, 60)])
def test_warm_start_from_optimum(n, r):
    a, V, s, g, lo, hi = random_problem(61 + n, n, r)
    H = dense_hessian(a, V, s)
    cold = solve_box_qp(a, V, s, g, lo, hi)
    assert cold.iterations < 30, cold.iterations
    warm = solve_box_qp(a, V, s, g, lo, hi, x0=cold.x)
    assert warm.iterations <= 1
    np.testing.assert_allclose(warm.x, cold.x, atol=1e-12)
    # from an independently computed optimum (quadprog) too
    x_qp = quadprog_box(H, g, lo, hi)
    warm2 = solve_box_qp(a, V, s, g, lo, hi, x0=x_qp)
    assert warm2.iterations <= 1
    assert kkt_violation(H, g, lo, hi, warm2.x, bound_tol=1e-12)[0] <= 1e-8


WELL_CONDITIONED = [(n, r, neg) for n, r in CASES for neg in (False, True)
                    if neg or n <= 50 or r == 1]


@pytest.mark.parametrize("n,r,negative", WELL_CONDITIONED)
def test_cold_start_iterations_modest(n, r, negative):
    for seed in range(3):
        a, V, s, g, lo, hi = random_problem(900 + 31 * seed + n + r, n, r, negative)
        res = solve_box_qp(a, V, s, g, lo, hi)
        assert res.status == Status.OK
        assert res.iterations < 30, res.iterations


def drag_shaped_problem(seed, n=60, k=15, alpha=0.1, mu=0.001):
    """The QP of thesis Eq. 4.5 in the normalised form: H = 2(α+μ) I + 2 RᵀR, g = 2(Rᵀm + α w0)."""
    rng = np.random.default_rng(seed)
    R = rng.normal(size=(3 * k, n)) * 0.1
    R[:, rng.random(n) < 0.3] = 0.0          # localized targets: many keys do not reach a given pin
    m = rng.normal(size=3 * k) * 0.3
    w0 = rng.uniform(0, 1, size=n)
    a = 2 * (alpha + mu)
    return a, R.T.copy(), np.full(3 * k, 2.0), 2 * (R.T @ m + alpha * w0), np.zeros(n), np.ones(n), w0


@pytest.mark.parametrize("seed", range(4))
def test_drag_shaped_problem_cold_and_warm(seed):
    a, V, s, g, lo, hi, w0 = drag_shaped_problem(seed)
    H = dense_hessian(a, V, s)
    res = solve_box_qp(a, V, s, g, lo, hi, x0=w0)
    assert res.status == Status.OK and res.iterations < 30
    x_qp = quadprog_box(H, g, lo, hi)
    np.testing.assert_allclose(res.x, x_qp, atol=1e-8)
    warm = solve_box_qp(a, V, s, g, lo, hi, x0=res.x)
    assert warm.iterations <= 1


@pytest.mark.xfail(strict=True, reason="known limitation (performance) of core/boxqp.py projected Newton: "
                                       "ill-conditioned n=300, r=60 problems with most variables bound need "
                                       "30-113 cold-start iterations (the active set is found a few variables "
                                       "at a time); it still converges within max_iter=500")
def test_cold_start_iterations_ill_conditioned():
    its = []
    for seed in range(4):
        a, V, s, g, lo, hi = random_problem(700 + seed, 300, 60, negative=False)
        its.append(solve_box_qp(a, V, s, g, lo, hi).iterations)
    assert max(its) < 30, its


def _stall_problem():
    rng = np.random.default_rng(3)
    n, r, a = 36, 27, 0.02
    V = rng.normal(size=(n, r))
    s = np.full(r, 2.0)
    g = rng.normal(size=n) * 2
    return a, V, s, g, -np.ones(n), np.ones(n)


def test_stall_problem_result_is_optimal():
    # the point returned on the stall problem below IS the optimum (so the failure there is the status)
    a, V, s, g, lo, hi = _stall_problem()
    H = dense_hessian(a, V, s)
    res = solve_box_qp(a, V, s, g, lo, hi)
    np.testing.assert_allclose(res.x, quadprog_box(H, g, lo, hi), atol=1e-10)
    assert kkt_violation(H, g, lo, hi, res.x)[0] <= 1e-8


def test_stall_at_optimum_reports_convergence():
    a, V, s, g, lo, hi = _stall_problem()
    res = solve_box_qp(a, V, s, g, lo, hi)
    assert res.status == Status.OK and res.iterations < 30, (res.status, res.iterations, res.residual)


def test_stall_warm_start_from_optimum():
    a, V, s, g, lo, hi = _stall_problem()
    x_opt = solve_box_qp(a, V, s, g, lo, hi).x      # optimal to 1e-10 (test_stall_problem_result_is_optimal)
    warm = solve_box_qp(a, V, s, g, lo, hi, x0=x_opt)
    assert warm.iterations <= 1, warm.iterations


def test_ill_conditioned_converges_within_default_max_iter():
    rng = np.random.default_rng(0)
    n, r, a = 300, 60, 0.05
    V = rng.normal(size=(n, r))
    s = rng.uniform(0.1, 3, size=r)
    x_u = rng.normal(size=n)
    g = a * x_u + V @ (s * (V.T @ x_u))
    lo = -rng.uniform(0.05, 1, size=n)
    hi = rng.uniform(0.05, 1, size=n)
    H = dense_hessian(a, V, s)
    res = solve_box_qp(a, V, s, g, lo, hi)
    assert res.status == Status.OK
    np.testing.assert_allclose(res.x, quadprog_box(H, g, lo, hi), atol=1e-6)


def test_warm_start_outside_box_is_projected():
    n, r = 20, 4
    a, V, s, g, lo, hi = random_problem(81, n, r)
    H = dense_hessian(a, V, s)
    x0 = np.full(n, 50.0)
    res = solve_box_qp(a, V, s, g, lo, hi, x0=x0)
    assert np.all(res.x >= lo) and np.all(res.x <= hi)
    np.testing.assert_allclose(res.x, quadprog_box(H, g, lo, hi), atol=1e-8)


def test_one_dimensional_V_accepted():
    n = 10
    rng = np.random.default_rng(91)
    v = rng.normal(size=n)
    a, s = 0.7, 2.0
    g = rng.normal(size=n) * 3
    lo, hi = -np.ones(n) * 0.4, np.ones(n) * 0.4
    res = solve_box_qp(a, v, s, g, lo, hi)
    H = a * np.eye(n) + s * np.outer(v, v)
    np.testing.assert_allclose(res.x, quadprog_box(H, g, lo, hi), atol=1e-9)


# --------------------------------------------------------------------------- input errors
def _small():
    rng = np.random.default_rng(5)
    n, r = 6, 2
    return rng.normal(size=(n, r)), np.ones(r), rng.normal(size=n), -np.ones(n), np.ones(n)


@pytest.mark.parametrize("a", [0.0, -1.0, float("nan")])
def test_nonpositive_a_raises(a):
    V, s, g, lo, hi = _small()
    with pytest.raises(ShapeSpaceError):
        solve_box_qp(a, V, s, g, lo, hi)


def test_zero_s_raises():
    V, s, g, lo, hi = _small()
    s = np.array([1.0, 0.0])
    with pytest.raises(ShapeSpaceError):
        solve_box_qp(1.0, V, s, g, lo, hi)


def test_lo_above_hi_raises():
    V, s, g, lo, hi = _small()
    lo[2] = 2.0
    with pytest.raises(ShapeSpaceError) as exc:
        solve_box_qp(1.0, V, s, g, lo, hi)
    assert exc.value.code == "range"


@pytest.mark.parametrize("r_s", [1, 3])
def test_V_s_mismatch_raises(r_s):
    V, _, g, lo, hi = _small()
    with pytest.raises(ShapeSpaceError) as exc:
        solve_box_qp(1.0, V, np.ones(r_s), g, lo, hi)
    assert exc.value.code == "shape"


def test_transposed_V_raises():
    V, s, g, lo, hi = _small()            # V is (6, 2), s has 2 entries
    with pytest.raises(ShapeSpaceError):
        solve_box_qp(1.0, V.T.copy(), s, g, lo, hi)   # (2, 6): wrong orientation


# --------------------------------------------------------------------------- the dual solver used for Eq. 4.5

def lsq_problem(seed, n=60, q=30):
    rng = np.random.default_rng(seed)
    R = rng.normal(size=(q, n)) * 0.3
    m = rng.normal(size=q)
    b = rng.uniform(0, 1, n)
    return R, m, b, np.zeros(n), np.ones(n)


def lsq_reference(R, m, c, b, lo, hi):
    """min ‖R x − m‖² + c‖x − b‖² over the box, as the QP ½xᵀHx − gᵀx for quadprog."""
    n = R.shape[1]
    H = 2 * (R.T @ R + c * np.eye(n))
    g = 2 * (R.T @ m + c * b)
    return quadprog_box(H, g, lo, hi)


def lsq_obj(R, m, c, b, x):
    r = R @ x - m
    return float(r @ r + c * (x - b) @ (x - b))


@pytest.mark.parametrize("c", [1.0, 0.1, 0.01])
@pytest.mark.parametrize("seed", range(3))
def test_dual_lsq_matches_quadprog(seed, c):
    R, m, b, lo, hi = lsq_problem(seed)
    x_ref = lsq_reference(R, m, c, b, lo, hi)
    f_ref = lsq_obj(R, m, c, b, x_ref)
    for dual0 in (None, 2 * (R @ b - m)):          # cold, and warm as solve_drag starts it
        res = solve_box_lsq_dual(R, m, c, b, lo, hi, dual0=dual0)
        assert res.status == Status.OK
        assert np.all(res.x >= lo) and np.all(res.x <= hi)
        assert abs(lsq_obj(R, m, c, b, res.x) - f_ref) <= 1e-9 * f_ref
        np.testing.assert_allclose(res.x, x_ref, atol=1e-7)
    # warm start from its own optimal dual: done at once
    again = solve_box_lsq_dual(R, m, c, b, lo, hi, dual0=res.dual)
    assert again.iterations <= 1


@pytest.mark.xfail(strict=True, reason="known limitation of solve_box_lsq_dual alone: iterations grow roughly "
                                       "like 1/sqrt(c); for c = 1e-4 it stops at max_iter with status NOT_CONVERGED. "
                                       "solve_drag detects the status and finishes in the primal "
                                       "(tests/core/test_manipulation.py small-alpha tests)")
@pytest.mark.parametrize("seed", range(2))
def test_dual_lsq_small_c(seed):
    R, m, b, lo, hi = lsq_problem(seed)
    c = 1e-4
    x_ref = lsq_reference(R, m, c, b, lo, hi)
    res = solve_box_lsq_dual(R, m, c, b, lo, hi, dual0=2 * (R @ b - m))
    assert res.status == Status.OK
    f_ref = lsq_obj(R, m, c, b, x_ref)
    assert abs(lsq_obj(R, m, c, b, res.x) - f_ref) <= 1e-9 * f_ref


@pytest.mark.parametrize("c", [0.0, -1.0])
def test_dual_lsq_nonpositive_c_raises(c):
    R, m, b, lo, hi = lsq_problem(0)
    with pytest.raises(ShapeSpaceError):
        solve_box_lsq_dual(R, m, c, b, lo, hi)


@pytest.mark.parametrize("kw, word", [({"tol": float("nan")}, "tol"), ({"tol": 0.0}, "tol"),
                                      ({"max_iter": -1}, "max_iter"), ({"max_iter": 2.5}, "max_iter"),
                                      ({"x0": np.full(6, np.nan)}, "x0")])
def test_bad_stopping_rule_or_start_raises_naming_it(kw, word):
    """Issue #10: a NaN tolerance used to run to max_iter silently; a NaN start is refused by name."""
    V, s, g, lo, hi = _small()
    with pytest.raises(ShapeSpaceError, match=word):
        solve_box_qp(1.0, V, s, g, lo, hi, **kw)
    if "x0" not in kw:
        R, m, b, lo2, hi2 = lsq_problem(0)
        with pytest.raises(ShapeSpaceError, match=word):
            solve_box_lsq_dual(R, m, 1.0, b, lo2, hi2, **kw)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_g_or_dual0_raises(bad):
    V, s, g, lo, hi = _small()
    g[1] = bad
    with pytest.raises(ShapeSpaceError) as exc:
        solve_box_qp(1.0, V, s, g, lo, hi)
    assert exc.value.code == "non_finite"
    R, m, b, lo2, hi2 = lsq_problem(0)
    dual0 = np.zeros(R.shape[0])
    dual0[0] = bad
    with pytest.raises(ShapeSpaceError) as exc:
        solve_box_lsq_dual(R, m, 1.0, b, lo2, hi2, dual0=dual0)
    assert exc.value.code == "non_finite"
