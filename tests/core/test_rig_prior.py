"""core.rig.prior and the learned prior in the rig solve (issue #25 item 2, Learned mode); core.rig.mirror.

References, written here independently of the code under test: numpy's mean/covariance for the training; for the
solve, a linear "rig" ``P(c) = A c + b`` whose prior-regularised problem ``‖A c + b − t‖² + (c − r)ᵀ W (c − r)``
is the stacked least-squares problem ``[A; Lᵀ] c ≈ [t − b; Lᵀ r]`` (``L Lᵀ = W``, ``r`` the controls at the start:
the linear path's Learned mode centres its prior on the weights at mouse-down): unbounded by
``numpy.linalg.lstsq``, bounded by ``scipy.optimize.lsq_linear``, plus the KKT conditions of the bounded QP checked
densely; for the mirror plane, surfaces mirrored across a known plane then moved by a known rigid motion.
"""
import numpy as np
import pytest
from scipy.optimize import lsq_linear

from core.result import ShapeSpaceError, Status
from core.rig import solve_controls
from core.rig.mirror import fit_mirror_plane
from core.rig.prior import train_control_prior
from core.rig.solve import bounded_step


def _samples(rng, f=40, n=5):
    mix = rng.normal(size=(n, n)) * np.array([1.0, 0.5, 0.2, 0.05, 0.01])[:n]
    return rng.normal(size=(f, 2)) @ rng.normal(size=(2, n)) * 0.3 + rng.normal(size=(f, n)) @ mix.T * 0.05 + 0.1


def test_training_is_the_sample_mean_and_covariance_plus_the_ridge_from_the_natural_scales():
    rng = np.random.default_rng(0)
    x = _samples(rng)
    s = np.array([2.0, 0.5, 1.0, 3.0, 0.1])
    unit, alpha, eps = 0.01, 0.1, 0.1
    p = train_control_prior(x, list("abcde"), s, unit, alpha, eps)
    np.testing.assert_allclose(p.mean, x.mean(0), rtol=1e-12)
    cov = np.cov(x, rowvar=False)
    sigma2 = np.mean(np.diag(cov) * s * s) / unit ** 2
    np.testing.assert_allclose(p.covariance, cov + np.diag(eps * sigma2 * unit ** 2 / s ** 2), rtol=1e-10)
    assert p.weight == pytest.approx(alpha * unit ** 2 * sigma2)
    np.testing.assert_allclose(p.precision, p.weight * np.linalg.inv(p.covariance), rtol=1e-8, atol=1e-12)
    d = x[3] - p.mean
    assert p.mahalanobis(x[3]) == pytest.approx(np.sqrt(d @ np.linalg.solve(p.covariance, d)), rel=1e-10)
    # an isotropic covariance in surface units is the Direct regulariser α/(1+ε) Σ (s (x − μ))²
    iso = rng.normal(size=(200000, 2)) / s[:2] * unit
    q = train_control_prior(iso, ["a", "b"], s[:2], unit, alpha, eps)
    dx = np.array([0.3, -0.2]) * unit / s[:2]
    assert q.energy(q.mean + dx) == pytest.approx(alpha / (1 + eps) * np.sum((s[:2] * dx) ** 2), rel=2e-2)


@pytest.mark.parametrize("bad, code", [("one", "prior_frames"), ("nan", "non_finite"), ("flat", "prior_constant"),
                                       ("shape", "shape")])
def test_bad_training_data_is_refused_by_name(bad, code):
    x = _samples(np.random.default_rng(1))
    names = list("abcde")
    if bad == "one":
        x = x[:1]
    elif bad == "nan":
        x[7, 2] = np.nan
    elif bad == "flat":
        x[:] = x[0]
    elif bad == "shape":
        names = names[:4]
    with pytest.raises(ShapeSpaceError) as exc:
        train_control_prior(x, names, np.ones(5), 1.0)
    assert exc.value.code == code
    if bad == "nan":
        assert "'c'" in str(exc.value) and "sample 7" in str(exc.value)


def _linear_rig(rng, p=6, n=5):
    A = rng.normal(size=(3 * p, n))
    b = rng.normal(size=3 * p)
    return A, b, (lambda c: (A @ c + b).reshape(p, 3))


def _reference(A, b, t, prior, r, lo=None, hi=None):
    L = np.linalg.cholesky(prior.precision)
    M = np.vstack([A, L.T])
    y = np.concatenate([t.reshape(-1) - b, L.T @ r])
    if lo is None:
        return np.linalg.lstsq(M, y, rcond=None)[0]
    return lsq_linear(M, y, bounds=(lo, hi), method="bvls", tol=1e-14).x


def _objective(A, b, t, prior, c, ref):
    r = A @ c + b - t.reshape(-1)
    d = c - ref
    return r @ r + d @ prior.precision @ d


def test_the_unbounded_prior_solve_is_the_closed_form_least_squares_answer():
    rng = np.random.default_rng(2)
    A, b, rig = _linear_rig(rng)
    prior = train_control_prior(_samples(rng), list("abcde"), np.ones(5), 1.0, alpha=0.5)
    t = rig(rng.normal(size=5) * 2.0) + rng.normal(size=(6, 3)) * 0.1       # not reachable exactly
    c0 = np.full(5, -0.4)                                                    # far from the prior's mean
    res = solve_controls(rig, c0, t, prior=prior, pin_tol=0.0, ftol=1e-14)
    ref = _reference(A, b, t, prior, c0)
    assert res.status == Status.OK
    np.testing.assert_allclose(res.x, ref, atol=1e-7 * (1 + np.abs(ref).max()))
    assert res.objective == pytest.approx(_objective(A, b, t, prior, ref, c0), rel=1e-9)
    hist = res.diagnostics["objective_history"]
    assert all(y <= x for x, y in zip(hist, hist[1:]))
    # the prior is centred on the start (as the linear path's Learned mode), never on the training mean:
    # without the data term's pull nothing moves
    far = solve_controls(rig, c0, t, prior=prior, weights=np.zeros(6), pin_tol=0.0, ftol=1e-14)
    np.testing.assert_allclose(far.x, c0, atol=1e-12)
    # an explicit reference is the centre
    r = np.linspace(-0.2, 0.3, 5)
    res = solve_controls(rig, c0, t, prior=prior, reference=r, pin_tol=0.0, ftol=1e-14)
    np.testing.assert_allclose(res.x, _reference(A, b, t, prior, r), atol=1e-7)


def test_the_bounded_prior_solve_matches_scipy_and_satisfies_the_kkt_conditions():
    rng = np.random.default_rng(3)
    A, b, rig = _linear_rig(rng)
    prior = train_control_prior(_samples(rng), list("abcde"), np.ones(5), 1.0, alpha=0.2)
    t = rig(np.array([2.0, -2.0, 1.5, 0.3, -1.0]))
    lo, hi = np.full(5, -0.5), np.full(5, 0.6)
    res = solve_controls(rig, np.zeros(5), t, lo=lo, hi=hi, prior=prior, pin_tol=0.0, ftol=1e-15, max_iter=200)
    ref = _reference(A, b, t, prior, np.zeros(5), lo, hi)
    assert res.status == Status.OK
    assert np.any(ref <= lo + 1e-9) or np.any(ref >= hi - 1e-9)              # bounds are active
    np.testing.assert_allclose(res.x, ref, atol=1e-6)
    assert res.objective <= _objective(A, b, t, prior, ref, np.zeros(5)) * (1 + 1e-9) + 1e-12
    # KKT of ½xᵀHx − gᵀx on the box: H = AᵀA + W, g = Aᵀ(t − b) + W r (r = the start, 0)
    W = prior.precision
    grad = (A.T @ A + W) @ res.x - A.T @ (t.reshape(-1) - b)
    free = (res.x > lo + 1e-9) & (res.x < hi - 1e-9)
    scale = np.abs(A.T @ (t.reshape(-1) - b)).max()
    assert np.abs(grad[free]).max(initial=0.0) <= 1e-6 * scale
    assert np.all(grad[res.x <= lo + 1e-9] >= -1e-6 * scale) and np.all(grad[res.x >= hi - 1e-9] <= 1e-6 * scale)


def test_a_prior_solve_leaves_channels_the_pins_do_not_need_at_the_start_and_moves_correlated_ones_along():
    """Channels 0 and 1 move together in the animation, 2 and 3 on their own (far from the start on average); the
    pin sees only channel 0.  Channels 2, 3 stay exactly at the start, channel 1 follows channel 0 as Σ says."""
    rng = np.random.default_rng(8)
    a = rng.normal(size=400)
    x = np.column_stack([a, 0.8 * a + 0.05 * rng.normal(size=400), 0.7 + 0.3 * rng.normal(size=400),
                         -0.6 + 0.2 * rng.normal(size=400)])
    x[:, 2:] -= x[:, 2:].mean(0) - [0.7, -0.6]                      # means far from the start (0)
    x[:, 2:] -= np.outer(x[:, 0] - x[:, 0].mean(), x[:, 2:].T @ (x[:, 0] - x[:, 0].mean())) / np.sum(
        (x[:, 0] - x[:, 0].mean()) ** 2)                                    # no correlation with channel 0
    prior = train_control_prior(x, list("abcd"), np.ones(4), 1.0, alpha=0.3)
    assert np.abs(prior.covariance[:2, 2:]).max() < 0.02
    A = np.zeros((3, 4))
    A[0, 0] = 1.0                                                           # one pin, moved by channel 0 only
    rig = (lambda c: (A @ c).reshape(1, 3))
    t = np.array([[0.5, 0.0, 0.0]])
    res = solve_controls(rig, np.zeros(4), t, prior=prior, pin_tol=0.0, ftol=1e-15)
    W = prior.precision
    closed = np.linalg.solve(A.T @ A + W, A.T @ t.reshape(-1))             # the same quadratic around 0
    np.testing.assert_allclose(res.x, closed, atol=1e-9)
    assert res.x[1] == pytest.approx(0.8 * res.x[0], rel=0.1)              # the correlated channel moves along
    assert np.abs(res.x[2:]).max() < 0.02 * res.x[0]                       # the others stay (not toward 0.7, -0.6)


def test_channels_the_animation_does_not_key_do_not_weaken_the_prior():
    """σ̄² is the mean of the non-zero variances (the linear path's PCA convention): appending channels the
    animation holds still leaves the keyed channels' precision block unchanged."""
    rng = np.random.default_rng(9)
    keyed = _samples(rng, n=2)
    base = train_control_prior(keyed, ["a", "b"], np.array([1.0, 2.0]), 0.5)
    z = (keyed - keyed.mean(0)) * np.array([1.0, 2.0]) / 0.5
    var = np.linalg.svd(z, compute_uv=False) ** 2 / (len(z) - 1)            # the linear path's PCA variances
    assert base.weight == pytest.approx(0.1 * 0.25 * var.mean(), rel=1e-10)
    for extra in (8, 48):
        x = np.hstack([keyed, np.full((len(keyed), extra), 0.3)])
        p = train_control_prior(x, [f"c{i}" for i in range(2 + extra)], np.r_[1.0, 2.0, np.ones(extra)], 0.5)
        np.testing.assert_allclose(p.precision[:2, :2], base.precision, rtol=1e-9)
        np.testing.assert_allclose(p.precision[:2, 2:], 0.0, atol=1e-12)
        assert list(p.keyed) == [True, True] + [False] * extra


def test_one_bounded_step_with_a_full_regulariser_is_the_box_least_squares_step():
    rng = np.random.default_rng(4)
    J, e = rng.normal(size=(12, 4)), rng.normal(size=12)
    B = rng.normal(size=(4, 4))
    W = B @ B.T + 0.1 * np.eye(4)
    c, ref = rng.normal(size=4) * 0.1, rng.normal(size=4)
    lo, hi = c - 0.2, c + 0.3
    D2, lam = np.abs(rng.normal(size=4)) + 0.5, 0.3
    d = bounded_step(J, e, W, c, ref, lam, D2, lo, hi)
    L = np.linalg.cholesky(W + np.diag(lam * D2))
    M = np.vstack([J, L.T])
    y = np.concatenate([-e, -np.linalg.solve(L, W @ (c - ref))])
    ref_d = lsq_linear(M, y, bounds=(lo - c, hi - c), method="bvls", tol=1e-14).x
    np.testing.assert_allclose(d, ref_d, atol=1e-9)


def test_a_prior_for_other_channels_is_refused():
    rng = np.random.default_rng(5)
    _A, _b, rig = _linear_rig(rng)
    prior = train_control_prior(_samples(rng, n=4), list("abcd"), np.ones(4), 1.0)
    with pytest.raises(ShapeSpaceError) as exc:
        solve_controls(rig, np.zeros(5), rig(np.ones(5)), prior=prior)
    assert exc.value.code == "shape"


# --------------------------------------------------------------------------- the mirror plane
def _mirrored_surface(rng, v=300):
    """A surface symmetric across x = 0.2 (v vertices on each side + centre vertices) and its mirror map."""
    half = rng.normal(size=(v, 3)) + np.array([1.2, 0.0, 0.0])
    other = half * np.array([-1.0, 1.0, 1.0]) + np.array([0.4, 0.0, 0.0])
    centre = np.column_stack([np.full(20, 0.2), rng.normal(size=(20, 2))])
    pts = np.vstack([half, other, centre])
    mirror = np.concatenate([np.arange(v, 2 * v), np.arange(v), np.arange(2 * v, 2 * v + 20)])
    return pts, mirror


def _rotation(rng):
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def test_the_mirror_plane_of_a_posed_symmetric_surface_is_the_moved_rest_plane():
    rng = np.random.default_rng(6)
    rest, mirror = _mirrored_surface(rng)
    R, t = _rotation(rng), np.array([0.3, -1.0, 2.0])
    posed = rest @ R.T + t
    plane = fit_mirror_plane(posed, mirror, rest[:, 0] - 0.2)
    n = R @ np.array([1.0, 0.0, 0.0])
    np.testing.assert_allclose(plane.normal, n, atol=1e-12)
    assert plane.offset == pytest.approx(n @ (R @ np.array([0.2, 0.0, 0.0]) + t), abs=1e-12)
    assert plane.residual < 1e-12 and plane.pairs == 300
    p = rng.normal(size=3)
    np.testing.assert_allclose(plane.reflect(p), R @ (np.array([-1, 1, 1]) * (R.T @ (p - t)) + [0.4, 0, 0]) + t,
                               atol=1e-12)
    np.testing.assert_allclose(plane.reflect(plane.reflect(p)), p, atol=1e-12)
    on = plane.project(p)
    assert on @ plane.normal == pytest.approx(plane.offset)
    np.testing.assert_allclose(on, 0.5 * (p + plane.reflect(p)), atol=1e-12)
    # an asymmetric pose: the residual says how far from symmetric it is
    bent = posed.copy()
    bent[:300] += 0.01
    assert fit_mirror_plane(bent, mirror, rest[:, 0] - 0.2).residual > 1e-3


def test_a_map_without_pairs_is_refused():
    rest, _ = _mirrored_surface(np.random.default_rng(7))
    with pytest.raises(ShapeSpaceError) as exc:
        fit_mirror_plane(rest, np.full(len(rest), -1), rest[:, 0])
    assert exc.value.code == "no_mirror"
