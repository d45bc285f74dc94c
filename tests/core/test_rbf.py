"""Scattered interpolation (thesis ch. 8) against independent references.

References: ``scipy.interpolate.RBFInterpolator`` (same kernel names and ``φ(ε r)`` scaling),
``scipy.interpolate.LinearNDInterpolator``, ``np.interp``, ``scipy.spatial.distance.cdist``,
``np.linalg.lstsq`` and hand-built matrices / analytic identities written out in this file.
No expected number comes from core.rbf itself.
"""
import itertools

import numpy as np
import pytest
from scipy.interpolate import LinearNDInterpolator, RBFInterpolator
from scipy.spatial import Delaunay
from scipy.spatial.distance import cdist

from core.rbf import (
    KERNELS,
    NormalizedRBF,
    RBFInterpolant,
    Shepard,
    SimplexLinear,
    choose_epsilon,
    fit_normalized_rbf,
    fit_rbf,
    loo_errors,
    pairwise_distances,
)
from core.result import ShapeSpaceError

# singular systems are expected in several tests; LAPACK's warning about them is noise here
pytestmark = pytest.mark.filterwarnings("ignore::scipy.linalg.LinAlgWarning", "ignore::RuntimeWarning")

# kernel -> polynomial degrees scipy accepts without a well-posedness warning (-1 .. 2)
SCIPY_DEGREES = {
    "gaussian": [-1, 0, 1, 2],
    "multiquadric": [0, 1, 2],
    "inverse_multiquadric": [-1, 0, 1, 2],
    "inverse_quadratic": [-1, 0, 1, 2],
    "linear": [0, 1, 2],
    "thin_plate_spline": [1, 2],
    "cubic": [1, 2],
    "quintic": [2],
}
# own kernels (incl. polyharmonic4, which scipy lacks) -> minimum degree (independent statement of theory)
MIN_DEGREE = {"gaussian": -1, "multiquadric": 0, "inverse_multiquadric": -1, "inverse_quadratic": -1,
              "linear": 0, "thin_plate_spline": 1, "cubic": 1, "quintic": 2, "polyharmonic4": 2}
POLYHARMONIC = {"linear": 0, "thin_plate_spline": 1, "cubic": 1, "quintic": 2, "polyharmonic4": 2}
EPS = 2.0  # shape parameter giving well-conditioned systems on the layouts below


# =========================================================================== layouts
def jittered_grid(dim, seed):
    """Well-separated centres in about [-1, 1]^dim (keeps every kernel matrix well conditioned)."""
    rng = np.random.default_rng(seed)
    if dim >= 4:
        return rng.uniform(-1, 1, size=(40, dim))
    n = {1: 7, 2: 5, 3: 3}[dim]
    g = np.linspace(-1.0, 1.0, n)
    grid = np.array(list(itertools.product(g, repeat=dim)))
    return grid + rng.uniform(-0.15, 0.15, grid.shape) * (2.0 / (n - 1))


def queries(dim, seed, m=40, lo=-1.2, hi=1.2):
    return np.random.default_rng(seed + 1000).uniform(lo, hi, size=(m, dim))


def all_scipy_cases():
    for kernel, degs in SCIPY_DEGREES.items():
        for deg in degs:
            yield kernel, deg


def own_kernel_cases():
    """Every kernel of core.rbf at its minimum degree and at degree 2."""
    for kernel in KERNELS:
        lo = MIN_DEGREE[kernel]
        for deg in sorted({lo, 2}):
            yield kernel, deg


# =========================================================================== scipy RBFInterpolator
@pytest.mark.parametrize("smoothing", [0.0, 0.1])
@pytest.mark.parametrize("dim", [1, 2, 3, 6])
@pytest.mark.parametrize("kernel,degree", list(all_scipy_cases()))
def test_fit_rbf_matches_scipy(kernel, degree, dim, smoothing):
    X = jittered_grid(dim, dim)
    K = X.shape[0]
    Q = queries(dim, dim)
    rng = np.random.default_rng(7 * dim + 3)
    vec = rng.normal(size=(K, 2))
    shp = rng.normal(size=(K, 4, 3))

    ref_vec = RBFInterpolator(X, vec, kernel=kernel, epsilon=EPS, degree=degree, smoothing=smoothing)(Q)
    ref_shp = RBFInterpolator(X, shp.reshape(K, -1), kernel=kernel, epsilon=EPS, degree=degree,
                              smoothing=smoothing)(Q)

    f_vec = fit_rbf(X, vec, kernel, epsilon=EPS, degree=degree, smoothing=smoothing)
    f_shp = fit_rbf(X, shp, kernel, epsilon=EPS, degree=degree, smoothing=smoothing)
    out_vec, out_shp = f_vec(Q), f_shp(Q)
    assert out_vec.shape == (Q.shape[0], 2)
    assert out_shp.shape == (Q.shape[0], 4, 3)
    np.testing.assert_allclose(out_vec, ref_vec, rtol=0, atol=1e-10)
    np.testing.assert_allclose(out_shp.reshape(Q.shape[0], -1), ref_shp, rtol=0, atol=1e-10)

    # cardinal form, from a fit made without values
    C = fit_rbf(X, None, kernel, epsilon=EPS, degree=degree, smoothing=smoothing).cardinal(Q)
    assert C.shape == (Q.shape[0], K)
    np.testing.assert_allclose(C @ vec, ref_vec, rtol=0, atol=1e-10)
    np.testing.assert_allclose(C @ shp.reshape(K, -1), ref_shp, rtol=0, atol=1e-10)




@pytest.mark.parametrize("kernel", list(SCIPY_DEGREES))
def test_default_degree_matches_scipy_default(kernel):
    """fit_rbf documents its default degree as 'scipy's choice'; scipy: max(min_degree, 0)."""
    X = jittered_grid(2, 11)
    d = np.random.default_rng(11).normal(size=X.shape[0])
    Q = queries(2, 11)
    ref = RBFInterpolator(X, d, kernel=kernel, epsilon=EPS)(Q)  # scipy default degree
    np.testing.assert_allclose(fit_rbf(X, d, kernel, epsilon=EPS)(Q), ref, rtol=0, atol=1e-10)


def test_one_dimensional_query_vector_is_a_column_for_1d_pose_space():
    X = jittered_grid(1, 4)
    d = np.sin(3 * X[:, 0])
    q = np.linspace(-1, 1, 9)
    ref = RBFInterpolator(X, d, kernel="cubic")(q[:, None])
    np.testing.assert_allclose(fit_rbf(X[:, 0], d, "cubic")(q), ref, rtol=0, atol=1e-10)


# =========================================================================== exactness
@pytest.mark.parametrize("dim", [1, 2, 3])
@pytest.mark.parametrize("kernel,degree", list(own_kernel_cases()))
def test_exact_at_centres(kernel, degree, dim):
    X = jittered_grid(dim, 20 + dim)
    K = X.shape[0]
    D = np.random.default_rng(dim).normal(size=(K, 3, 2))
    f = fit_rbf(X, D, kernel, epsilon=EPS, degree=degree)
    np.testing.assert_allclose(f(X), D, rtol=0, atol=1e-9)
    np.testing.assert_allclose(f.cardinal(X), np.eye(K), rtol=0, atol=1e-9)


# =========================================================================== polynomial reproduction
def _poly_data(dim, degree, rng_seed):
    """Random polynomial of total degree ``degree``, evaluated by hand; returns a callable."""
    rng = np.random.default_rng(rng_seed)
    c0 = rng.normal()
    c1 = rng.normal(size=dim) if degree >= 1 else np.zeros(dim)
    c2 = rng.normal(size=(dim, dim)) if degree >= 2 else np.zeros((dim, dim))

    def p(x):
        return c0 + x @ c1 + np.einsum("mi,ij,mj->m", x, c2, x)
    return p


@pytest.mark.parametrize("smoothing", [0.0, 0.3])
@pytest.mark.parametrize("dim", [1, 2, 3])
@pytest.mark.parametrize("kernel,degree,pdeg", [
    ("thin_plate_spline", 1, 1), ("cubic", 1, 1), ("quintic", 2, 2), ("quintic", 2, 1),
    ("thin_plate_spline", 2, 2), ("polyharmonic4", 2, 2), ("linear", 0, 0), ("linear", 1, 1),
    ("gaussian", 0, 0), ("gaussian", 1, 1), ("gaussian", 2, 2), ("multiquadric", 2, 2),
    ("inverse_quadratic", 1, 1),
])
def test_polynomial_reproduction(kernel, degree, pdeg, dim, smoothing):
    X = jittered_grid(dim, 30 + dim)
    p = _poly_data(X.shape[1], pdeg, 5 * dim + pdeg)
    f = fit_rbf(X, p(X), kernel, epsilon=EPS, degree=degree, smoothing=smoothing)
    Q = queries(dim, 3, m=60, lo=-1.5, hi=1.5)  # inside and outside the examples' box
    np.testing.assert_allclose(f(Q), p(Q), rtol=0, atol=1e-9)


def test_affine_polynomial_does_not_reproduce_quadratic():
    """Sanity: the reproduction above is a property of the degree, not of any smooth data."""
    X = jittered_grid(2, 32)
    p = _poly_data(X.shape[1], 2, 99)
    f = fit_rbf(X, p(X), "thin_plate_spline", degree=1)
    Q = queries(2, 4)
    assert np.max(np.abs(f(Q) - p(Q))) > 1e-4


# =========================================================================== invariances
@pytest.mark.parametrize("kernel,degree", list(own_kernel_cases()))
def test_translation_invariance(kernel, degree):
    X = jittered_grid(2, 41)
    Q = queries(2, 41)
    D = np.random.default_rng(41).normal(size=(X.shape[0], 2))
    t = np.array([3.7, -2.2])
    a = fit_rbf(X, D, kernel, epsilon=EPS, degree=degree, smoothing=0.05)(Q)
    b = fit_rbf(X + t, D, kernel, epsilon=EPS, degree=degree, smoothing=0.05)(Q + t)
    np.testing.assert_allclose(b, a, rtol=0, atol=1e-9)


@pytest.mark.parametrize("s", [0.13, 7.3])
@pytest.mark.parametrize("kernel,degree", list(own_kernel_cases()))
def test_scaling_positions_and_inverse_epsilon(kernel, degree, s):
    X = jittered_grid(3, 42)
    Q = queries(3, 42)
    D = np.random.default_rng(42).normal(size=(X.shape[0], 2))
    a = fit_rbf(X, D, kernel, epsilon=EPS, degree=degree, smoothing=0.05)(Q)
    b = fit_rbf(s * X, D, kernel, epsilon=EPS / s, degree=degree, smoothing=0.05)(s * Q)
    np.testing.assert_allclose(b, a, rtol=0, atol=1e-9)


@pytest.mark.parametrize("s", [0.13, 7.3])
@pytest.mark.parametrize("kernel", list(POLYHARMONIC))
def test_polyharmonic_scale_invariance_without_epsilon_change(kernel, s):
    """φ(s r) = s^k φ(r) (+ s^k log s · r^k for the log kernels, which the polynomial absorbs)."""
    X = jittered_grid(2, 43)
    Q = queries(2, 43)
    D = np.random.default_rng(43).normal(size=(X.shape[0], 2))
    deg = POLYHARMONIC[kernel]
    a = fit_rbf(X, D, kernel, epsilon=1.0, degree=deg)(Q)
    b = fit_rbf(s * X, D, kernel, epsilon=1.0, degree=deg)(s * Q)
    np.testing.assert_allclose(b, a, rtol=0, atol=1e-9)
    # and the cardinal functions are the same
    Ca = fit_rbf(X, None, kernel, degree=deg).cardinal(Q)
    Cb = fit_rbf(s * X, None, kernel, degree=deg).cardinal(s * Q)
    np.testing.assert_allclose(Cb, Ca, rtol=0, atol=1e-9)


@pytest.mark.parametrize("kernel,s", [("quintic", 10.0), ("quintic", 90.0), ("quintic", 1e-3), ("cubic", 180.0),
                                      ("thin_plate_spline", 1000.0), ("polyharmonic4", 30.0)])
def test_polyharmonic_scale_invariance_in_other_units(kernel, s):
    X = jittered_grid(2, 43)
    Q = queries(2, 43)
    D = np.random.default_rng(43).normal(size=(X.shape[0], 2))
    deg = POLYHARMONIC[kernel]
    a = fit_rbf(X, D, kernel, degree=deg)(Q)
    if kernel in SCIPY_DEGREES:  # the scaled problem is solvable: scipy reproduces the unscaled interpolant
        ref = RBFInterpolator(s * X, D, kernel=kernel, degree=deg)(s * Q)
        np.testing.assert_allclose(ref, a, rtol=0, atol=1e-9)
    b = fit_rbf(s * X, D, kernel, degree=deg)(s * Q)
    np.testing.assert_allclose(b, a, rtol=0, atol=1e-9)


def test_gaussian_is_not_scale_invariant_without_epsilon_change():
    """Sanity for the test above: a kernel with a length scale changes when only positions scale."""
    X = jittered_grid(2, 43)
    Q = queries(2, 43)
    D = np.random.default_rng(43).normal(size=(X.shape[0], 2))
    a = fit_rbf(X, D, "gaussian", epsilon=EPS, degree=1)(Q)
    b = fit_rbf(3.0 * X, D, "gaussian", epsilon=EPS, degree=1)(3.0 * Q)
    assert np.max(np.abs(a - b)) > 1e-3


# =========================================================================== partition of unity
@pytest.mark.parametrize("smoothing", [0.0, 0.2])
@pytest.mark.parametrize("kernel,degree", [c for c in own_kernel_cases() if c[1] >= 0]
                         + [("gaussian", 0), ("inverse_multiquadric", 1)])
def test_cardinal_rows_sum_to_one_with_constant_term(kernel, degree, smoothing):
    X = jittered_grid(3, 50)
    Q = queries(3, 50, m=80, lo=-2, hi=2)
    C = fit_rbf(X, None, kernel, epsilon=EPS, degree=degree, smoothing=smoothing).cardinal(Q)
    np.testing.assert_allclose(C.sum(axis=1), 1.0, rtol=0, atol=1e-9)


def test_cardinal_rows_do_not_sum_to_one_without_polynomial():
    X = jittered_grid(2, 51)
    Q = queries(2, 51, lo=-2, hi=2)
    C = fit_rbf(X, None, "gaussian", epsilon=EPS, degree=-1).cardinal(Q)
    assert np.max(np.abs(C.sum(axis=1) - 1.0)) > 1e-3


# =========================================================================== smoothing
def test_smoothing_is_not_exact_and_converges_to_exact_fit():
    X = jittered_grid(2, 60)
    d = np.random.default_rng(60).normal(size=X.shape[0])
    Q = queries(2, 60)
    exact = fit_rbf(X, d, "thin_plate_spline", degree=1)
    assert np.max(np.abs(fit_rbf(X, d, "thin_plate_spline", degree=1, smoothing=0.1)(X) - d)) > 1e-3
    lams = [1e-1, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6]
    res = [np.max(np.abs(fit_rbf(X, d, "thin_plate_spline", degree=1, smoothing=lam)(X) - d)) for lam in lams]
    gap = [np.max(np.abs(fit_rbf(X, d, "thin_plate_spline", degree=1, smoothing=lam)(Q) - exact(Q)))
           for lam in lams]
    assert all(r > 0 for r in res)
    assert all(a > b for a, b in zip(res, res[1:]))
    assert all(a > b for a, b in zip(gap, gap[1:]))
    # first-order convergence: f_λ = f_0 + O(λ)
    assert res[-1] < 1e-4 and gap[-1] < 1e-4
    ratio = np.array(gap[2:]) / np.array(lams[2:])
    assert ratio.max() / ratio.min() < 1.5


@pytest.mark.parametrize("kernel", ["gaussian", "inverse_quadratic", "multiquadric"])
def test_large_smoothing_degree0_tends_to_mean(kernel):
    X = jittered_grid(2, 61)
    d = np.random.default_rng(61).normal(size=(X.shape[0], 2))
    Q = queries(2, 61)
    errs = []
    for lam in [1e3, 1e5, 1e7]:
        f = fit_rbf(X, d, kernel, epsilon=EPS, degree=0, smoothing=lam)
        errs.append(np.max(np.abs(f(Q) - d.mean(axis=0))))
    # weights are O(|d|/λ): deviation from the constant least-squares fit shrinks like 1/λ
    assert errs[-1] < 1e-5
    assert errs[1] < errs[0] / 50 and errs[2] < errs[1] / 50
    # and the whole path agrees with scipy's smoothed fit
    lam = 1e5
    ref = RBFInterpolator(X, d, kernel=kernel, epsilon=EPS, degree=0, smoothing=lam)(Q)
    np.testing.assert_allclose(fit_rbf(X, d, kernel, epsilon=EPS, degree=0, smoothing=lam)(Q), ref,
                               rtol=0, atol=1e-12)


def test_large_smoothing_degree1_tends_to_least_squares_affine():
    X = jittered_grid(2, 62)
    K = X.shape[0]
    d = np.random.default_rng(62).normal(size=K)
    Q = queries(2, 62)
    A = np.hstack([np.ones((K, 1)), X])
    coef = np.linalg.lstsq(A, d, rcond=None)[0]
    ls = np.hstack([np.ones((Q.shape[0], 1)), Q]) @ coef
    errs = [np.max(np.abs(fit_rbf(X, d, "thin_plate_spline", degree=1, smoothing=lam)(Q) - ls))
            for lam in [1e3, 1e5, 1e7]]
    assert errs[-1] < 1e-5
    assert errs[1] < errs[0] / 50 and errs[2] < errs[1] / 50


# =========================================================================== errors
def _fit_data(dim=2, seed=70):
    X = jittered_grid(dim, seed)
    return X, np.random.default_rng(seed).normal(size=(X.shape[0], 2))


def test_error_unknown_kernel():
    X, d = _fit_data()
    with pytest.raises(ShapeSpaceError, match="unknown kernel") as ei:
        fit_rbf(X, d, "wendland")
    assert ei.value.code == "kernel"


@pytest.mark.parametrize("eps", [0.0, -1.0, np.nan])
def test_error_epsilon_not_positive(eps):
    X, d = _fit_data()
    with pytest.raises(ShapeSpaceError, match="epsilon") as ei:
        fit_rbf(X, d, "gaussian", epsilon=eps)
    assert ei.value.code == "range"


def test_error_negative_smoothing():
    X, d = _fit_data()
    with pytest.raises(ShapeSpaceError, match="smoothing") as ei:
        fit_rbf(X, d, "gaussian", smoothing=-1e-3)
    assert ei.value.code == "range"


def test_error_nan_smoothing_names_smoothing():
    X, d = _fit_data()
    with pytest.raises(ShapeSpaceError) as ei:
        fit_rbf(X, d, "gaussian", smoothing=np.nan)
    assert ei.value.code == "range" and "duplicate" not in str(ei.value)


def test_error_infinite_epsilon_names_epsilon():
    X, d = _fit_data()
    with pytest.raises(ShapeSpaceError, match="epsilon") as ei:
        fit_rbf(X, d, "gaussian", epsilon=np.inf)
    assert ei.value.code == "range"


@pytest.mark.parametrize("kernel,degree", [("thin_plate_spline", 0), ("cubic", -1), ("quintic", 1),
                                           ("multiquadric", -1), ("linear", -1), ("polyharmonic4", 1)])
def test_error_degree_below_kernel_minimum(kernel, degree):
    X, d = _fit_data()
    with pytest.raises(ShapeSpaceError, match="degree") as ei:
        fit_rbf(X, d, kernel, degree=degree)
    assert ei.value.code == "degree"


@pytest.mark.parametrize("dim,K,degree", [(2, 2, 1), (2, 5, 2), (3, 3, 1), (6, 27, 2), (1, 2, 2)])
def test_error_too_few_centres_for_polynomial(dim, K, degree):
    # number of monomials of total degree <= degree in dim variables: C(dim + degree, degree)
    from math import comb
    assert K < comb(dim + degree, degree)
    X = np.random.default_rng(K).uniform(-1, 1, size=(K, dim))
    with pytest.raises(ShapeSpaceError, match="too few") as ei:
        fit_rbf(X, None, "gaussian", degree=degree)
    assert ei.value.code == "too_few"
    # exactly enough is fine
    n = comb(dim + degree, degree)
    fit_rbf(np.random.default_rng(1).uniform(-1, 1, size=(n, dim)), None, "gaussian", degree=degree)


@pytest.mark.parametrize("kernel", ["gaussian", "inverse_quadratic", "multiquadric", "linear",
                                    "thin_plate_spline", "cubic", "quintic"])
def test_error_duplicate_centres_singular(kernel):
    X, d = _fit_data()
    Xd = np.vstack([X, X[3:4]])
    dd = np.vstack([d, d[3:4]])
    deg = max(MIN_DEGREE[kernel], 1)
    with pytest.raises(ShapeSpaceError, match="singular") as ei:
        fit_rbf(Xd, dd, kernel, epsilon=EPS, degree=deg)
    assert ei.value.code == "singular"
    # smoothing makes the same examples solvable
    f = fit_rbf(Xd, dd, kernel, epsilon=EPS, degree=deg, smoothing=0.1)
    ref = RBFInterpolator(Xd, dd, kernel=kernel, epsilon=EPS, degree=deg, smoothing=0.1)(X)
    np.testing.assert_allclose(f(X), ref, rtol=0, atol=1e-10)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_error_non_finite_centres_or_values(bad):
    X, d = _fit_data()
    Xb = X.copy()
    Xb[2, 1] = bad
    with pytest.raises(ShapeSpaceError, match="centers") as ei:
        fit_rbf(Xb, d, "gaussian")
    assert ei.value.code == "non_finite"
    db = d.copy()
    db[4, 0] = bad
    with pytest.raises(ShapeSpaceError, match="values") as ei:
        fit_rbf(X, db, "gaussian")
    assert ei.value.code == "non_finite"


def test_error_values_wrong_number_of_rows():
    X, d = _fit_data()
    with pytest.raises(ShapeSpaceError, match="rows") as ei:
        fit_rbf(X, d[:-1], "gaussian")
    assert ei.value.code == "shape"


def test_error_query_wrong_dimension():
    X, d = _fit_data(dim=2)
    f = fit_rbf(X, d, "gaussian")
    for q in (np.zeros((4, 3)), np.zeros(3), np.zeros((2, 1))):
        with pytest.raises(ShapeSpaceError, match="columns") as ei:
            f(q)
        assert ei.value.code == "shape"
        with pytest.raises(ShapeSpaceError, match="columns"):
            f.cardinal(q)
    with pytest.raises(ShapeSpaceError) as ei:
        f(np.zeros((2, 2, 2)))
    assert ei.value.code == "shape"
    with pytest.raises(ShapeSpaceError, match="NaN") as ei:
        f(np.array([[0.0, np.nan]]))
    assert ei.value.code == "non_finite"


def test_error_call_without_values():
    X, _ = _fit_data()
    f = fit_rbf(X, None, "gaussian")
    with pytest.raises(ShapeSpaceError, match="without values") as ei:
        f(X)
    assert ei.value.code == "no_values"


def test_error_is_a_valueerror():
    with pytest.raises(ValueError):
        fit_rbf(np.zeros((3, 2)) + np.arange(3)[:, None], None, "nope")


def test_error_no_centres():
    with pytest.raises(ShapeSpaceError):
        fit_rbf(np.zeros((0, 2)), np.zeros((0,)), "gaussian", degree=-1)


# =========================================================================== leave-one-out
def _brute_loo(X, d, kernel, eps, degree, smoothing=0.0, use_scipy=False):
    K = X.shape[0]
    out = np.empty_like(d, dtype=float)
    for k in range(K):
        keep = np.arange(K) != k
        if use_scipy:
            pred = RBFInterpolator(X[keep], d[keep], kernel=kernel, epsilon=eps, degree=degree,
                                   smoothing=smoothing)(X[k:k + 1])[0]
        else:
            pred = fit_rbf(X[keep], d[keep], kernel, eps, degree, smoothing)(X[k:k + 1])[0]
        out[k] = d[k] - pred
    return out


@pytest.mark.parametrize("smoothing", [0.0, 0.05])
@pytest.mark.parametrize("kernel,degree", [("gaussian", -1), ("gaussian", 1), ("thin_plate_spline", 1)])
def test_loo_errors_match_brute_force(kernel, degree, smoothing):
    X = jittered_grid(2, 80)
    rng = np.random.default_rng(80)
    d_scalar = np.sin(2 * X[:, 0]) * np.cos(X[:, 1]) + 0.1 * rng.normal(size=X.shape[0])
    d_vec = np.column_stack([d_scalar, rng.normal(size=X.shape[0])])
    for d in (d_scalar, d_vec):
        e = loo_errors(X, d, kernel, EPS, degree, smoothing)
        assert e.shape == d.shape
        np.testing.assert_allclose(e, _brute_loo(X, d, kernel, EPS, degree, smoothing, use_scipy=True),
                                   rtol=0, atol=1e-8)
        np.testing.assert_allclose(e, _brute_loo(X, d, kernel, EPS, degree, smoothing), rtol=0, atol=1e-8)


def test_loo_errors_shape_valued():
    X = jittered_grid(3, 81)
    D = np.random.default_rng(81).normal(size=(X.shape[0], 3, 2))
    e = loo_errors(X, D, "gaussian", EPS, 1)
    assert e.shape == D.shape
    ref = _brute_loo(X, D.reshape(X.shape[0], -1), "gaussian", EPS, 1, use_scipy=True)
    np.testing.assert_allclose(e.reshape(X.shape[0], -1), ref, rtol=0, atol=1e-8)


def test_choose_epsilon_minimises_brute_force_loo_rms():
    X = jittered_grid(2, 90)
    # smooth function plus a little measurement noise
    d = np.sin(1.5 * X[:, 0]) + 0.5 * X[:, 1] ** 2 + 0.05 * np.random.default_rng(5).normal(size=X.shape[0])
    cands = np.geomspace(0.3, 8.0, 9)
    eps, scores = choose_epsilon(X, d, "gaussian", degree=1, candidates=cands)
    brute = np.array([np.sqrt(np.mean(_brute_loo(X, d, "gaussian", c, 1, use_scipy=True) ** 2)) for c in cands])
    np.testing.assert_allclose(scores, brute, rtol=1e-6, atol=0)
    assert eps == cands[int(np.argmin(brute))]
    chosen = brute[int(np.argmin(brute))]
    assert chosen <= brute[0] and chosen <= brute[-1]
    assert cands[0] < eps < cands[-1]  # the smooth data prefer an interior width here


def test_choose_epsilon_vector_values_and_singular_candidate():
    X = jittered_grid(2, 91)
    d = np.column_stack([np.cos(X[:, 0] + X[:, 1]), X[:, 0] * X[:, 1]])
    cands = [1e-9, 1.0, 3.0]  # ε → 0 makes the Gaussian matrix all ones: singular
    eps, scores = choose_epsilon(X, d, "gaussian", degree=-1, candidates=cands)
    assert np.isinf(scores[0])
    brute = [np.sqrt(np.mean(_brute_loo(X, d, "gaussian", c, -1, use_scipy=True) ** 2)) for c in cands[1:]]
    np.testing.assert_allclose(scores[1:], brute, rtol=1e-6, atol=0)
    assert eps == cands[1 + int(np.argmin(brute))]


# =========================================================================== normalised RBF
def _phi(kernel, r):
    return {"gaussian": np.exp(-r ** 2), "inverse_multiquadric": 1 / np.sqrt(1 + r ** 2),
            "inverse_quadratic": 1 / (1 + r ** 2)}[kernel]


@pytest.mark.parametrize("kernel", ["gaussian", "inverse_multiquadric", "inverse_quadratic"])
def test_normalized_rbf_against_hand_computation(kernel):
    X = jittered_grid(2, 100)
    K = X.shape[0]
    Q = queries(2, 100, m=60, lo=-2, hi=2)
    model = fit_normalized_rbf(X, kernel, EPS)
    assert isinstance(model, NormalizedRBF)

    def norm_rows(P):
        dist = np.sqrt(((P[:, None, :] - X[None, :, :]) ** 2).sum(-1))
        ph = _phi(kernel, EPS * dist)
        return ph / ph.sum(axis=1, keepdims=True)

    A = norm_rows(X)
    ref = np.linalg.solve(A.T, norm_rows(Q).T).T
    C = model.cardinal(Q)
    np.testing.assert_allclose(C, ref, rtol=0, atol=1e-10)
    # exact at the examples
    np.testing.assert_allclose(model.cardinal(X), np.eye(K), rtol=0, atol=1e-9)
    # partition of unity: A·1 = 1 (rows normalised) ⇒ A⁻¹·1 = 1 ⇒ c(x)·1 = φ̂(x)·1 = 1
    np.testing.assert_allclose(A @ np.ones(K), 1.0, rtol=0, atol=1e-14)
    np.testing.assert_allclose(C.sum(axis=1), 1.0, rtol=0, atol=1e-9)


@pytest.mark.parametrize("kernel", ["thin_plate_spline", "multiquadric", "linear", "cubic", "nope"])
def test_normalized_rbf_rejects_non_positive_kernels(kernel):
    with pytest.raises(ShapeSpaceError, match="positive kernel") as ei:
        fit_normalized_rbf(jittered_grid(2, 101), kernel)
    assert ei.value.code == "kernel"


def test_normalized_rbf_duplicates_singular_and_bad_query():
    X = jittered_grid(2, 102)
    with pytest.raises(ShapeSpaceError, match="singular"):
        fit_normalized_rbf(np.vstack([X, X[:1]]))
    with pytest.raises(ShapeSpaceError, match="columns"):
        fit_normalized_rbf(X).cardinal(np.zeros((2, 3)))


# =========================================================================== Shepard
@pytest.mark.parametrize("power", [1.0, 2.0, 3.5])
def test_shepard_against_hand_weights(power):
    X = jittered_grid(3, 110)
    K = X.shape[0]
    Q = queries(3, 110, m=50, lo=-2, hi=2)
    sh = Shepard(X, power)
    C = sh.cardinal(Q)
    dist = np.sqrt(((Q[:, None, :] - X[None, :, :]) ** 2).sum(-1))
    w = dist ** (-power)
    np.testing.assert_allclose(C, w / w.sum(axis=1, keepdims=True), rtol=1e-12, atol=1e-15)
    assert np.all(C >= 0)
    np.testing.assert_allclose(C.sum(axis=1), 1.0, rtol=0, atol=1e-12)
    # exact at the examples, also when mixed into a batch of other points
    np.testing.assert_allclose(sh.cardinal(X), np.eye(K), rtol=0, atol=1e-12)
    mixed = np.vstack([Q[:3], X[5:6], Q[3:5]])
    Cm = sh.cardinal(mixed)
    np.testing.assert_allclose(Cm[3], np.eye(K)[5], rtol=0, atol=0)
    np.testing.assert_allclose(Cm[[0, 1, 2, 4, 5]], C[:5], rtol=1e-12, atol=1e-15)


def test_shepard_default_power_is_inverse_square():
    X = jittered_grid(2, 111)
    q = np.array([[0.1, -0.27]])
    w = 1.0 / np.sum((X - q) ** 2, axis=1)
    np.testing.assert_allclose(Shepard(X).cardinal(q)[0], w / w.sum(), rtol=1e-12)


# =========================================================================== simplex-linear
@pytest.mark.parametrize("dim", [2, 3])
def test_simplex_linear_matches_linear_nd_inside_hull(dim):
    rng = np.random.default_rng(120 + dim)
    X = rng.uniform(-1, 1, size=(25, dim))
    K = X.shape[0]
    Q = rng.uniform(-1, 1, size=(300, dim))
    ref = LinearNDInterpolator(X, np.eye(K))(Q)
    inside = np.isfinite(ref).all(axis=1)
    assert inside.sum() > 50 and (~inside).sum() > 5
    C = SimplexLinear(X).cardinal(Q)
    np.testing.assert_allclose(C[inside], ref[inside], rtol=0, atol=1e-10)
    assert np.all(C[inside] >= -1e-12)
    np.testing.assert_allclose(C.sum(axis=1), 1.0, rtol=0, atol=1e-12)
    # at most dim + 1 nonzero weights per point (one simplex)
    assert np.all((np.abs(C[inside]) > 1e-14).sum(axis=1) <= dim + 1)
    # exact at the examples
    np.testing.assert_allclose(SimplexLinear(X).cardinal(X), np.eye(K), rtol=0, atol=1e-10)


@pytest.mark.parametrize("dim", [2, 3])
def test_simplex_linear_reproduces_affine_inside_hull(dim):
    rng = np.random.default_rng(130 + dim)
    X = rng.uniform(-1, 1, size=(30, dim))
    a, b = rng.normal(), rng.normal(size=dim)
    Q = rng.uniform(-1, 1, size=(300, dim))
    inside = Delaunay(X).find_simplex(Q) >= 0
    C = SimplexLinear(X).cardinal(Q[inside])
    np.testing.assert_allclose(C @ (a + X @ b), a + Q[inside] @ b, rtol=0, atol=1e-10)


@pytest.mark.parametrize("dim", [2, 3])
def test_simplex_linear_outside_hull_is_nearest_one_hot(dim):
    rng = np.random.default_rng(140 + dim)
    X = rng.uniform(-1, 1, size=(20, dim))
    dirs = rng.normal(size=(40, dim))
    Q = 3.0 * dirs / np.linalg.norm(dirs, axis=1, keepdims=True)  # far outside [-1, 1]^dim
    C = SimplexLinear(X).cardinal(Q)
    nearest = np.argmin(cdist(Q, X), axis=1)
    np.testing.assert_array_equal(C, np.eye(X.shape[0])[nearest])


def test_simplex_linear_1d_is_piecewise_linear_and_constant_outside():
    rng = np.random.default_rng(150)
    x = rng.permutation(np.sort(rng.uniform(-1, 1, 9)))  # unsorted on purpose
    d = rng.normal(size=9)
    q = np.concatenate([np.linspace(-1.5, 1.5, 101), x])
    C = SimplexLinear(x[:, None]).cardinal(q[:, None])
    order = np.argsort(x)
    ref = np.interp(q, x[order], d[order])  # np.interp extrapolates with the end values
    np.testing.assert_allclose(C @ d, ref, rtol=0, atol=1e-12)
    below, above = q < x.min(), q > x.max()
    assert below.any() and above.any()
    np.testing.assert_array_equal(C[below], np.tile(np.eye(9)[np.argmin(x)], (below.sum(), 1)))
    np.testing.assert_array_equal(C[above], np.tile(np.eye(9)[np.argmax(x)], (above.sum(), 1)))
    np.testing.assert_allclose(SimplexLinear(x[:, None]).cardinal(x[:, None]), np.eye(9), rtol=0, atol=1e-12)
    assert np.all(C >= 0)


@pytest.mark.parametrize("dim,K", [(2, 2), (2, 1), (3, 3)])
def test_simplex_linear_too_few_points(dim, K):
    with pytest.raises(ShapeSpaceError, match="needs more than") as ei:
        SimplexLinear(np.random.default_rng(K).uniform(size=(K, dim)))
    assert ei.value.code == "too_few"


def test_simplex_linear_bad_query_dimension():
    S = SimplexLinear(np.random.default_rng(0).uniform(size=(6, 2)))
    with pytest.raises(ShapeSpaceError, match="columns"):
        S.cardinal(np.zeros((2, 3)))


@pytest.mark.parametrize("dim", [2, 3])
def test_simplex_linear_degenerate_centres_raise_shapespace_error(dim):
    t = np.linspace(0.0, 1.0, 5)[:, None]
    if dim == 2:
        X = np.hstack([t, 2 * t])  # five poses on one line of a 2-D pose space
    else:
        X = np.vstack([np.hstack([t, 2 * t, 0 * t]), [[0.5, 0.0, 0.0]]])  # six poses in the plane z = 0
    with pytest.raises(ShapeSpaceError):
        SimplexLinear(X)


# =========================================================================== distances
def test_pairwise_distances_equals_cdist():
    rng = np.random.default_rng(160)
    a, b = rng.normal(size=(13, 5)), rng.normal(size=(7, 5))
    D = pairwise_distances(a, b)
    assert D.shape == (13, 7)
    np.testing.assert_allclose(D, cdist(a, b), rtol=1e-14, atol=0)
    np.testing.assert_allclose(D, np.linalg.norm(a[:, None, :] - b[None, :, :], axis=-1), rtol=1e-13, atol=0)
    # lists and integer input are accepted
    np.testing.assert_allclose(pairwise_distances([[0, 0]], [[3, 4]]), [[5.0]])


def test_interpolant_attributes():
    X = jittered_grid(2, 170)
    f = fit_rbf(X, None, "cubic", degree=2, smoothing=0.25)
    assert isinstance(f, RBFInterpolant)
    assert f.n_centers == X.shape[0] and f.kernel == "cubic" and f.degree == 2 and f.smoothing == 0.25
    np.testing.assert_array_equal(f.centers, X)
