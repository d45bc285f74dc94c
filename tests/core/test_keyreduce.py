"""core.animation's key reduction (thesis 3.5.5): fewest linear keys, smooth Bézier keys, Hermite evaluation.

References: brute force over all key subsets; ``scipy.interpolate.CubicHermiteSpline``; exact parabolas.
"""
import itertools

import numpy as np
import pytest

from core.keyreduce import curve_slopes, hermite, reduce_keys, reduce_keys_bezier
from core.result import ShapeSpaceError


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


def test_reduce_keys_bezier_held_pose_costs_two_keys_at_any_length():
    # a pose held for 3,000 frames (exactly equal samples, so zero three-point slopes inside): stage 1 spans it
    # with one segment from its second to its second-to-last sample, beyond the searched span; the curve
    # through the keys (SciPy's CubicHermiteSpline) is within the tolerance everywhere
    from scipy.interpolate import CubicHermiteSpline
    t = np.arange(3400.0)
    v = np.where(t < 200, np.sin(t / 30.0) * 0.3, 0.3 * np.sin(200 / 30.0))
    v[3200:] += np.sin((t[3200:] - 3200) / 25.0) * 0.2
    idx, kv, km = reduce_keys_bezier(t, v, 0.01, refine=False)
    np.testing.assert_array_equal(kv, v[idx])
    held = (idx > 200) & (idx < 3200)
    assert idx[held].tolist() == [201, 3199]
    for refine in (False, True):
        idx, kv, km = reduce_keys_bezier(t, v, 0.01, refine=refine)
        assert np.abs(CubicHermiteSpline(t[idx], kv, km)(t) - v).max() <= 0.01
        assert np.sum((idx > 200) & (idx < 3200)) <= 2


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


@pytest.mark.parametrize("noise", [1e-12, 1e-7, 5e-5])
def test_reduce_keys_bezier_nearly_held_pose_costs_two_keys(noise):
    # a pose held to within a solver's round-off or capture noise (not exactly equal samples) for 3,000 frames:
    # stage 1 spans it with one segment, as an exactly held pose, and the curve through the keys (SciPy's
    # CubicHermiteSpline) is within the tolerance everywhere
    from scipy.interpolate import CubicHermiteSpline
    rng = np.random.default_rng(7)
    t = np.arange(3400.0)
    v = np.where(t < 200, np.sin(t / 30.0) * 0.3, 0.3 * np.sin(200 / 30.0))
    v[3200:] += np.sin((t[3200:] - 3200) / 25.0) * 0.2
    v[205:3195] += rng.uniform(-noise, noise, 2990)
    for refine in (False, True):
        idx, kv, km = reduce_keys_bezier(t, v, 0.01, refine=refine)
        assert np.abs(CubicHermiteSpline(t[idx], kv, km)(t) - v).max() <= 0.01
        assert np.sum((idx > 210) & (idx < 3190)) == 0


def test_reduce_keys_bezier_slow_drift_is_split_until_within_tolerance():
    # a pose drifting slowly (each step within the "nearly held" band, 0.06 over the whole run): the Hermite from
    # its first sample to its last is off by more than the tolerance, so the run is halved until its pieces are
    # within it; the keys stay within the tolerance everywhere, and stage 2 then refits the whole run as one
    from scipy.interpolate import CubicHermiteSpline
    t = np.arange(6000.0)
    v = 0.06 * (0.5 - 0.5 * np.cos(np.pi * t / 6000.0)) ** 3 + 1e-5 * np.sin(t / 3.0)
    for tol in (0.01, 0.005):
        h = CubicHermiteSpline(t[[0, 5999]], v[[0, 5999]], curve_slopes(t, v)[[0, 5999]])(t)
        assert np.abs(h - v).max() > tol
        for refine in (False, True):
            idx, kv, km = reduce_keys_bezier(t, v, tol, refine=refine)
            assert np.abs(CubicHermiteSpline(t[idx], kv, km)(t) - v).max() <= tol
            assert idx.size <= 3
