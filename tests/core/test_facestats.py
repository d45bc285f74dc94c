"""Face-space statistics (thesis ch. 6), inpainting (9.3) and pose-space confidence (9.1-9.2).

References are computed independently here: covariances and Mahalanobis distances with plain
numpy, chi-square tails with scipy.stats, Gaussian-process formulas with np.linalg.solve, and a
small BVH reader (test-only) for a real CMU knee channel.
"""
import os

import numpy as np
import pytest
from scipy import stats

from core.facespace import (FaceGaussian, cubic_fill, fit_face_gaussian, inpaint_curve, linear_fill,
                            linear_interpolate, shell_interpolate)
from core.result import Result, ShapeSpaceError

BVH = "/work/shared/data/cmu_mocap/131_01.bvh"


def correlated_faces(rng, f=3000, n=6):
    A = rng.normal(size=(n, n))
    return rng.normal(size=(f, n)) @ A + rng.normal(size=n), A.T @ A


def ar2_sine(rng, T, period=50.0, noise=0.3):
    e = np.zeros(T)
    for i in range(2, T):
        e[i] = 1.6 * e[i - 1] - 0.8 * e[i - 2] + noise * rng.normal()
    return np.sin(2 * np.pi * np.arange(T) / period) + 0.3 * e


def rms(a, b, mask):
    return float(np.sqrt(np.mean((np.asarray(a) - np.asarray(b))[mask] ** 2)))


# ------------------------------------------------------------------ face Gaussian
def test_fit_matches_numpy_covariance_and_whitening_round_trips():
    rng = np.random.default_rng(0)
    W, _ = correlated_faces(rng)
    g = fit_face_gaussian(W)
    assert isinstance(g, FaceGaussian) and not g.regularised and g.ridge == 0.0
    C = np.cov(W, rowvar=False)
    np.testing.assert_allclose(g.mean, W.mean(axis=0), atol=1e-12)
    np.testing.assert_allclose((g.eigvecs * g.eigvals) @ g.eigvecs.T, C, rtol=1e-10, atol=1e-10)
    Z = g.whiten(W)
    np.testing.assert_allclose(np.cov(Z, rowvar=False), np.eye(6), atol=1e-9)
    np.testing.assert_allclose(g.unwhiten(Z), W, atol=1e-9)
    assert g.dimension == 6.0 and g.shell_radius == pytest.approx(np.sqrt(5.0))


def test_face_norm_and_percentile_match_direct_formulas():
    rng = np.random.default_rng(1)
    W, _ = correlated_faces(rng, n=4)
    g = fit_face_gaussian(W)
    C = np.cov(W, rowvar=False)
    w = rng.normal(size=(3, 5, 4)) * 3
    diff = w - W.mean(axis=0)
    maha = np.sqrt(np.einsum("...i,ij,...j->...", diff, np.linalg.inv(C), diff))
    np.testing.assert_allclose(g.face_norm(w), maha, rtol=1e-10)
    np.testing.assert_allclose(g.percentile(w), stats.chi2.cdf(maha ** 2, 4), rtol=1e-10)
    assert g.face_norm(g.mean) == 0.0 and g.percentile(g.mean) == 0.0


def test_high_dimensional_mass_sits_in_a_shell_and_the_mean_face_is_atypical():
    rng = np.random.default_rng(2)
    n = 50
    W = rng.normal(size=(5000, n)) * rng.uniform(0.5, 2.0, n)
    g = fit_face_gaussian(W)
    norms = g.face_norm(W)
    assert abs(np.median(norms) - np.sqrt(n)) < 0.5
    assert np.std(norms) < 1.0                       # thin shell: width O(1) at radius ≈ 7
    assert np.mean(norms < 0.5 * np.sqrt(n)) == 0.0  # nothing near the mean
    test = np.vstack([g.mean, W[:200], g.mean + 3 * (W[0] - g.mean)])
    res = g.plausibility(test, alpha=0.01)
    assert isinstance(res, Result) and res.status == 1
    assert res.value[0] == "too_average" and res.value[-1] == "too_extreme"
    assert np.mean(res.value[1:-1] == "typical") > 0.97
    np.testing.assert_allclose(res.diagnostics["norm"], g.face_norm(test))
    codes = {i.code for i in res.issues}
    assert {"too_average", "too_extreme"} <= codes
    # about alpha of the training frames are flagged
    idx, reasons = g.implausible_frames(W, alpha=0.05)
    assert 0.02 < idx.size / W.shape[0] < 0.08
    assert set(reasons) <= {"too_average", "too_extreme"} and len(reasons) == idx.size
    ok = g.plausibility(W[5], alpha=0.01)
    assert ok.value.shape == () and (ok.status == 0) == (ok.value == "typical")


def test_too_few_frames_regularise_and_say_so():
    rng = np.random.default_rng(3)
    W = rng.normal(size=(4, 10))
    g = fit_face_gaussian(W)
    assert g.regularised and "ridge" in g.message and "4 frames for 10 channels" in g.message
    assert g.ridge == pytest.approx(1e-3 * np.mean(np.var(W, axis=0, ddof=1)))
    assert 2.9 < g.dimension <= 3.0                  # rank of 4 centred frames
    assert np.isfinite(g.whiten(rng.normal(size=10))).all()
    np.testing.assert_allclose(g.unwhiten(g.whiten(W)), W, atol=1e-10)


def test_constant_channels_are_listed_and_whitened_with_the_ridge():
    rng = np.random.default_rng(4)
    W = rng.normal(size=(500, 4))
    W[:, 2] = 0.25
    g = fit_face_gaussian(W)
    assert g.regularised and g.diagnostics["constant_channels"] == [2] and "constant" in g.message
    w = g.mean.copy()
    w[2] += np.sqrt(g.ridge)                           # one ridge standard deviation on the flat channel
    assert g.face_norm(w) == pytest.approx(1.0, rel=1e-6)
    allflat = fit_face_gaussian(np.ones((10, 3)))
    assert allflat.ridge == 1e-6 and "every channel is constant" in allflat.message
    explicit = fit_face_gaussian(rng.normal(size=(100, 3)), ridge=0.5)
    assert explicit.regularised and explicit.ridge == 0.5 and explicit.dimension < 3


def test_face_gaussian_bad_input_names_the_argument():
    with pytest.raises(ShapeSpaceError, match="weights must have shape"):
        fit_face_gaussian(np.zeros(5))
    with pytest.raises(ShapeSpaceError, match="weights contains NaN"):
        fit_face_gaussian(np.array([[0.0, np.nan], [1.0, 2.0], [0.0, 1.0]]))
    with pytest.raises(ShapeSpaceError, match="ridge"):
        fit_face_gaussian(np.eye(3), ridge=-1.0)
    g = fit_face_gaussian(np.random.default_rng(5).normal(size=(50, 3)))
    with pytest.raises(ShapeSpaceError, match=r"w must have shape \(\.\.\., 3\)"):
        g.face_norm(np.zeros(4))
    with pytest.raises(ShapeSpaceError, match="alpha"):
        g.plausibility(g.mean, alpha=1.5)
    with pytest.raises(ShapeSpaceError, match="frames_weights"):
        g.implausible_frames(g.mean)


# ------------------------------------------------------------------ shell interpolation
def _equal_norm_pair(g, rng, radius):
    z0, z1 = rng.normal(size=(2, g.mean.size))
    return g.unwhiten(radius * z0 / np.linalg.norm(z0)), g.unwhiten(radius * z1 / np.linalg.norm(z1))


def test_shell_keeps_the_norm_and_linear_collapses_toward_the_mean():
    rng = np.random.default_rng(6)
    W, _ = correlated_faces(rng, n=8)
    g = fit_face_gaussian(W)
    w0, w1 = _equal_norm_pair(g, rng, g.shell_radius)
    t = np.linspace(0.0, 1.0, 11)
    shell, lin = shell_interpolate(g, w0, w1, t), linear_interpolate(w0, w1, t)
    assert shell.shape == lin.shape == (11, 8)
    np.testing.assert_allclose(g.face_norm(shell), g.shell_radius, rtol=1e-10)
    assert np.array_equal(shell[0], w0) and np.array_equal(shell[-1], w1)
    assert np.array_equal(lin[0], w0) and np.array_equal(lin[-1], w1)
    z0, z1 = g.whiten(w0), g.whiten(w1)
    assert g.face_norm(lin[5]) == pytest.approx(np.linalg.norm(z0 + z1) / 2, rel=1e-10)
    assert g.face_norm(lin[5]) < g.shell_radius - 1e-3
    # the path is a great circle in whitened space: constant angular speed
    Z = g.whiten(shell)
    ang = np.arccos(np.clip(np.sum(Z[:-1] * Z[1:], axis=1) / g.shell_radius ** 2, -1, 1))
    np.testing.assert_allclose(ang, ang[0], rtol=1e-6)


def test_shell_radius_goes_linearly_between_unequal_norms():
    rng = np.random.default_rng(7)
    g = fit_face_gaussian(correlated_faces(rng, n=5)[0])
    w0 = g.unwhiten(np.array([1.0, 0, 0, 0, 0]))
    w1 = g.unwhiten(np.array([0, 3.0, 0, 0, 0]))
    t = np.array([0.0, 0.25, 0.5, 1.0])
    np.testing.assert_allclose(g.face_norm(shell_interpolate(g, w0, w1, t)), 1 + 2 * t, rtol=1e-10)
    same_dir = shell_interpolate(g, w0, g.unwhiten(np.array([4.0, 0, 0, 0, 0])), t)
    np.testing.assert_allclose(same_dir, linear_interpolate(w0, g.unwhiten(np.array([4.0, 0, 0, 0, 0])), t),
                               atol=1e-10)


def test_shell_special_cases_antipodal_and_mean_endpoint():
    rng = np.random.default_rng(8)
    g = fit_face_gaussian(correlated_faces(rng, n=4)[0])
    z = np.array([0.5, -1.0, 2.0, 0.3])
    w0, w1 = g.unwhiten(z), g.unwhiten(-z)
    t = np.linspace(0, 1, 9)
    path = shell_interpolate(g, w0, w1, t)
    assert np.isfinite(path).all()
    np.testing.assert_allclose(g.face_norm(path), np.linalg.norm(z), rtol=1e-10)
    Zm = g.whiten(path[4])
    assert abs(Zm @ z) < 1e-9 * np.linalg.norm(z) ** 2        # halfway: perpendicular to both ends
    # an endpoint at the mean face has no direction: the radial line, same as the lerp
    np.testing.assert_allclose(shell_interpolate(g, g.mean, w1, t), linear_interpolate(g.mean, w1, t), atol=1e-12)
    np.testing.assert_allclose(shell_interpolate(g, g.mean, g.mean, t), np.tile(g.mean, (9, 1)), atol=1e-12)
    # 1-D: the shell is two points, so antipodal ends fall back to the lerp
    g1 = fit_face_gaussian(rng.normal(size=(100, 1)))
    a, b = g1.unwhiten([1.0]), g1.unwhiten([-1.0])
    np.testing.assert_allclose(shell_interpolate(g1, a, b, t), linear_interpolate(a, b, t), atol=1e-12)


def test_shell_bad_input():
    g = fit_face_gaussian(np.random.default_rng(9).normal(size=(50, 3)))
    with pytest.raises(ShapeSpaceError, match=r"w1 must have shape \(3,\)"):
        shell_interpolate(g, np.zeros(3), np.zeros(4), [0.5])
    with pytest.raises(ShapeSpaceError, match="t must be"):
        shell_interpolate(g, np.zeros(3), np.ones(3), [1.5])
    with pytest.raises(ShapeSpaceError, match="FaceGaussian"):
        shell_interpolate(None, np.zeros(3), np.ones(3), [0.5])


# ------------------------------------------------------------------ inpainting
def _gap_mask(T, starts, length):
    known = np.ones(T, bool)
    for s in starts:
        known[s:s + length] = False
    return known


def test_conditional_mean_beats_linear_on_held_out_gaps_and_is_exact_at_known_samples():
    rng = np.random.default_rng(10)
    x = ar2_sine(rng, 2000)
    known = _gap_mask(2000, np.arange(40, 1960, 97), 10)
    res = inpaint_curve(np.where(known, x, np.nan), known)
    assert res.status == 0 and res.diagnostics["method"] == "window_covariance"
    assert len(res.diagnostics["gaps"]) == 20 and res.diagnostics["window_lengths"][0] == 10 + 2 * 10
    assert res.diagnostics["gaps"][0] == (40, 50)
    assert np.array_equal(res.value[known], x[known])
    assert np.isfinite(res.value).all()
    assert rms(res.value, x, ~known) < 0.85 * rms(linear_fill(x, known), x, ~known)


def test_autocovariance_fallback_when_windows_are_scarce():
    rng = np.random.default_rng(11)
    x = ar2_sine(rng, 400)
    known = np.ones(400, bool)
    known[3::10] = known[4::10] = False           # no fully-known window of length 18
    res = inpaint_curve(x, known)
    assert res.diagnostics["method"] == "autocovariance" and res.status == 1
    assert "autocovariance" in res.message and any(i.code == "autocovariance_fallback" for i in res.issues)
    assert np.array_equal(res.value[known], x[known])
    assert rms(res.value, x, ~known) < rms(linear_fill(x, known), x, ~known)


def test_given_squared_exponential_covariance_matches_direct_gaussian_conditioning():
    rng = np.random.default_rng(12)
    T, ell = 60, 4.0
    t = np.arange(T)
    K = np.exp(-0.5 * ((t[:, None] - t[None, :]) / ell) ** 2)
    x = np.linalg.cholesky(K + 1e-8 * np.eye(T)) @ rng.normal(size=T)
    known = _gap_mask(T, [25], 5)
    gamma = lambda lags: np.exp(-0.5 * (np.asarray(lags) / ell) ** 2)    # noqa: E731
    ridge = 1e-8
    res = inpaint_curve(x, known, ridge=ridge, autocovariance=gamma)
    assert res.diagnostics["method"] == "given_autocovariance" and res.diagnostics["contexts"] == [8]
    # direct: known samples within 8 frames of the gap, mean = mean of all known samples
    mu = x[known].mean()
    k = np.r_[17:25, 30:38]
    u = np.arange(25, 30)
    direct = mu + K[np.ix_(u, k)] @ np.linalg.solve(K[np.ix_(k, k)] + ridge * np.eye(k.size), x[k] - mu)
    np.testing.assert_allclose(res.value[u], direct, rtol=1e-8, atol=1e-8)
    assert rms(res.value, x, ~known) < rms(linear_fill(x, known), x, ~known)


def test_channel_that_is_a_linear_combination_is_recovered_almost_exactly():
    rng = np.random.default_rng(13)
    T = 1500
    a, b = ar2_sine(rng, T, period=40), ar2_sine(rng, T, period=65)
    X = np.column_stack([a, b, 0.7 * a - 1.3 * b + 0.2])
    known = np.ones_like(X, bool)
    for s in (300, 700, 1100):
        known[s:s + 25, 2] = False                 # only the derived channel is missing
    res = inpaint_curve(X, known)
    assert res.value.shape == X.shape and np.array_equal(res.value[known], X[known])
    err = rms(res.value, X, ~known)
    assert err < 1e-3 * np.std(X[:, 2])
    assert err < 0.01 * rms(linear_fill(X, known), X, ~known)
    # the same gap in one channel alone: no partners to learn from, far worse
    alone = inpaint_curve(X[:, 2], known[:, 2])
    assert rms(alone.value, X[:, 2], ~known[:, 2]) > 100 * err


def test_gaps_at_the_curve_ends_and_constant_channels():
    rng = np.random.default_rng(14)
    T = 1200
    X = np.column_stack([ar2_sine(rng, T), np.full(T, 3.5)])
    known = np.ones(T, bool)
    known[:12] = known[-6:] = known[600:610] = False
    res = inpaint_curve(np.where(known[:, None], X, np.nan), known)
    assert res.diagnostics["gaps"] == [(0, 12), (600, 610), (T - 6, T)]
    assert res.status == 1 and "one side only" in res.message
    assert sum(i.code == "end_gap" for i in res.issues) == 2
    assert res.diagnostics["constant_channels"] == [1] and "constant" in res.message
    np.testing.assert_array_equal(res.value[:, 1], 3.5)
    assert np.isfinite(res.value).all() and np.array_equal(res.value[known], X[known])
    assert rms(res.value[:, 0], X[:, 0], ~known) < np.std(X[:, 0])
    flat = inpaint_curve(np.full(50, 2.0), _gap_mask(50, [10], 5))
    assert flat.diagnostics["method"] == "constant" and np.all(flat.value == 2.0)


def test_reference_fills():
    x = np.array([0.0, np.nan, 2.0, np.nan, np.nan, 8.0, 7.0])
    known = np.isfinite(x)
    np.testing.assert_allclose(linear_fill(x, known), [0, 1, 2, 4, 6, 8, 7])
    cub = cubic_fill(np.arange(10.0) ** 2, _gap_mask(10, [4], 2))
    np.testing.assert_allclose(cub, np.arange(10.0) ** 2, atol=1e-9)     # a cubic spline reproduces x²
    end = linear_fill(np.array([np.nan, 1.0, 3.0]), np.array([False, True, True]))
    np.testing.assert_allclose(end, [1.0, 1.0, 3.0])


def test_inpaint_bad_input_names_the_argument():
    x = np.arange(20.0)
    with pytest.raises(ShapeSpaceError, match=r"known must have shape \(20,\)"):
        inpaint_curve(x, np.ones(19, bool))
    with pytest.raises(ShapeSpaceError, match="known must be a boolean mask"):
        inpaint_curve(x, np.ones(20))
    with pytest.raises(ShapeSpaceError, match="no sample as known"):
        inpaint_curve(x, np.zeros(20, bool))
    bad = x.copy()
    bad[3] = np.nan
    with pytest.raises(ShapeSpaceError, match="NaN or infinite entries at known samples"):
        inpaint_curve(bad, np.ones(20, bool))
    with pytest.raises(ShapeSpaceError, match="values must have shape"):
        inpaint_curve(np.zeros((2, 3, 4)), np.ones(2, bool))
    mask = np.ones((20, 2), bool)
    mask[:, 1] = False
    with pytest.raises(ShapeSpaceError, match=r"channel\(s\) \[1\] have no known samples"):
        inpaint_curve(np.zeros((20, 2)), mask)
    with pytest.raises(ShapeSpaceError, match="window"):
        inpaint_curve(x, _gap_mask(20, [5], 2), window=0)
    with pytest.raises(ShapeSpaceError, match="autocovariance must have shape"):
        inpaint_curve(x, _gap_mask(20, [5], 2), autocovariance=np.ones(3))


def _read_bvh(path):
    """Minimal BVH reader: channel names ("Joint.Xrotation") and the (frames, channels) motion block."""
    with open(path) as fh:
        lines = fh.read().splitlines()
    names, joint = [], None
    for i, line in enumerate(lines):
        tok = line.split()
        if tok and tok[0] in ("ROOT", "JOINT"):
            joint = tok[1]
        elif tok and tok[0] == "CHANNELS":
            names += [f"{joint}.{c}" for c in tok[2:]]
        elif tok and tok[0] == "MOTION":
            frames = int(lines[i + 1].split()[1])
            data = np.array([[float(v) for v in row.split()] for row in lines[i + 3:i + 3 + frames]])
            return names, data
    raise ValueError("no MOTION block")


@pytest.mark.skipif(not os.path.exists(BVH), reason="CMU mocap sample not available")
def test_real_knee_rotation_gaps_beat_linear_fill():
    names, data = _read_bvh(BVH)
    assert data.shape == (994, len(names))
    knee = data[:, names.index("LeftKnee.Xrotation")]
    rng = np.random.default_rng(15)
    ratios = []
    for _ in range(3):
        known = _gap_mask(knee.size, np.arange(30, knee.size - 30, 60) + rng.integers(0, 20), 10)
        res = inpaint_curve(knee, known)
        assert np.array_equal(res.value[known], knee[known])
        ratios.append(rms(res.value, knee, ~known) / rms(linear_fill(knee, known), knee, ~known))
    assert np.mean(ratios) < 0.5


# --------------------------------------------------------------------------- context channel choice
def test_context_channels_picks_the_correlated_channel_and_respects_the_budget():
    from core.facespace import context_channels
    rng = np.random.default_rng(11)
    T = 600
    t = np.arange(T)
    driver = np.sin(t / 13.0) + 0.3 * np.sin(t / 5.0)
    X = np.column_stack([driver, rng.normal(size=T), 0.8 * driver + 0.01 * rng.normal(size=T),
                         np.full(T, 2.0), rng.normal(size=T)])
    known = np.ones(T, bool)
    known[300:310] = False
    chosen = context_channels(X, 0, known, 10)
    assert chosen[0] == 0 and chosen[1] == 2                 # the correlated one first
    assert 3 not in chosen                                    # a constant channel carries nothing
    # the windows of a short curve cannot support any extra channel (L = 30, 2 L (k + 1) > T − L + 1)
    assert list(context_channels(X[:100], 0, known[:100], 10)) == [0]


def test_context_channels_bad_input():
    from core.facespace import context_channels
    with pytest.raises(ShapeSpaceError):
        context_channels(np.zeros((50, 3)), 5, np.ones(50, bool), 5)
    with pytest.raises(ShapeSpaceError):
        context_channels(np.zeros((50, 3)), 0, np.ones(49, bool), 5)
