"""Minimax fits of Bézier key reduction (#11): the exchange algorithm against scipy's LP solver."""
import numpy as np
import pytest
from scipy.optimize import linprog

import core.keyreduce as keyreduce
from core.keyreduce import _segment_basis, chebyshev_fit, hermite, reduce_keys_bezier


def _lp_minimax(A, y):
    k = A.shape[1]
    ones = np.ones((y.size, 1))
    res = linprog(np.r_[np.zeros(k), 1.0], A_ub=np.block([[A, -ones], [-A, -ones]]), b_ub=np.r_[y, -y],
                  bounds=[(None, None)] * k + [(0, None)], method="highs")
    assert res.status == 0
    return float(res.x[k])


def _random_system(rng, trial):
    """Random dense systems and the two-key Hermite systems key reduction builds (three segments)."""
    if trial % 2:
        m = int(rng.integers(2, 300))
        A = rng.normal(size=(m, 4)) * rng.uniform(0.1, 10.0, 4)
        if trial % 5 == 0:
            A[:, 3] = 2.0 * A[:, 0]                                   # rank deficient
        return A, rng.normal(size=m)
    t = np.arange(0.0, float(rng.integers(3, 120)))
    A = _segment_basis(t[0], t[-1], t)
    y = np.convolve(rng.normal(size=t.size + 20), np.hanning(15), "same")[10:t.size + 10]
    return A, y + rng.normal(size=t.size) * 0.01


@pytest.mark.parametrize("seed", range(4))
def test_chebyshev_fit_matches_linprog_on_random_segments(seed):
    rng = np.random.default_rng(seed)
    for trial in range(60):
        A, y = _random_system(rng, trial)
        x, err = chebyshev_fit(A, y)
        assert x is not None
        assert err == pytest.approx(np.abs(A @ x - y).max(), abs=1e-14)
        assert err == pytest.approx(_lp_minimax(A, y), rel=1e-7, abs=1e-12)


def test_chebyshev_fit_stops_early_with_a_lower_bound():
    rng = np.random.default_rng(11)
    A, y = rng.normal(size=(80, 4)), rng.normal(size=80)
    best = chebyshev_fit(A, y)[1]
    x, bound = chebyshev_fit(A, y, stop_above=0.5 * best)
    assert x is None and 0.5 * best < bound <= best + 1e-12


def test_chebyshev_fit_degenerate_inputs():
    x, err = chebyshev_fit(np.zeros((5, 4)), np.arange(5.0))
    assert err == 4.0 and np.all(x == 0)
    x, err = chebyshev_fit(np.eye(3, 4), np.ones(3))                  # fewer rows than unknowns: exact
    assert err < 1e-14


def test_key_reduction_calls_no_general_lp_solver(monkeypatch):
    import scipy.optimize

    def refuse(*args, **kwargs):
        raise AssertionError("linprog called")
    monkeypatch.setattr(scipy.optimize, "linprog", refuse)
    rng = np.random.default_rng(3)
    t = np.arange(1.0, 401.0)
    v = np.convolve(rng.normal(size=440), np.hanning(31), "same")[20:420] * 0.08 + rng.normal(size=400) * 0.002
    calls = []
    real, batched = keyreduce.chebyshev_fit, keyreduce._chebyshev_batch      # the scalar and the batched fits
    monkeypatch.setattr(keyreduce, "chebyshev_fit", lambda *a, **k: calls.append(1) or real(*a, **k))
    monkeypatch.setattr(keyreduce, "_chebyshev_batch", lambda *a, **k: calls.append(1) or batched(*a, **k))
    idx, kv, km = reduce_keys_bezier(t, v, 0.002)
    assert calls, "the refinement never needed a minimax fit; the test would prove nothing"
    assert np.abs(hermite(t[idx], kv, km, t) - v).max() <= 0.002
