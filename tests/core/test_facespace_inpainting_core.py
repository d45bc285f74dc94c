"""Covariance inpainting and superresolution of curves (core.facespace.inpainting, thesis 9.3): Gaussian-process
formulas with np.linalg.solve, linear and cubic references, and a small BVH reader (test-only) for a real CMU
knee channel."""
import os

import numpy as np
import pytest

from core.facespace import cubic_fill, inpaint_curve, linear_fill
from core.result import ShapeSpaceError

BVH = "/work/shared/data/cmu_mocap/131_01.bvh"


def ar2_sine(rng, T, period=50.0, noise=0.3):
    e = np.zeros(T)
    for i in range(2, T):
        e[i] = 1.6 * e[i - 1] - 0.8 * e[i - 2] + noise * rng.normal()
    return np.sin(2 * np.pi * np.arange(T) / period) + 0.3 * e


def rms(a, b, mask):
    return float(np.sqrt(np.mean((np.asarray(a) - np.asarray(b))[mask] ** 2)))


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
