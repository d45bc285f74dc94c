"""The tolerance guarantee of Bézier key reduction (3.5.5), checked by evaluations that share no code with
:mod:`core.keyreduce`: every reduced curve, evaluated the way Blender evaluates Bézier keys with aligned handles
a third of each segment along the key's slope (de Casteljau on the four control points; and SciPy's
``CubicHermiteSpline``), is within the tolerance of the dense curve at every frame — on random curves (smooth,
noisy, held poses, steps, clipped at 0 like capture weights) and on the shipped Live Link Face take."""
import os

import numpy as np
import pytest
from scipy.interpolate import CubicHermiteSpline

from core.keyreduce import reduce_keys_bezier_curves
from core.retarget.capture import read_live_link_csv, resample

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CSV = os.path.join(ROOT, "assets", "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")


def _de_casteljau(kt, kv, km, t):
    """Blender's Bézier segment with handles at (t₀ + h/3, v₀ + h m₀/3) and (t₁ − h/3, v₁ − h m₁/3): the time
    coordinate is then linear in the curve parameter, so the parameter of frame t is (t − t₀) / h."""
    seg = np.clip(np.searchsorted(kt, t, side="right") - 1, 0, kt.size - 2)
    h = kt[seg + 1] - kt[seg]
    u = (t - kt[seg]) / h
    p0, p3 = kv[seg], kv[seg + 1]
    p1, p2 = p0 + h * km[seg] / 3.0, p3 - h * km[seg + 1] / 3.0
    a, b, c = p0 + u * (p1 - p0), p1 + u * (p2 - p1), p2 + u * (p3 - p2)
    d, e = a + u * (b - a), b + u * (c - b)
    return d + u * (e - d)


def _check(frames, dense, tol, keys):
    for j, (idx, kv, km) in enumerate(keys):
        assert idx[0] == 0 and idx[-1] == frames.size - 1 and np.all(np.diff(idx) > 0)
        kt = frames[idx]
        for curve in (_de_casteljau(kt, kv, km, frames), CubicHermiteSpline(kt, kv, km)(frames)):
            assert np.abs(curve - dense[:, j]).max() <= tol, f"curve {j} off by more than {tol}"


def _random_curves(rng, n):
    t = np.arange(1.0, n + 1.0)
    cols = []
    for w in (5, 15, 41, 121):
        smooth = np.convolve(rng.normal(size=n + 2 * w), np.hanning(w), "same")[w:n + w] * 3.0 / w
        cols.append(smooth + rng.normal(size=n) * rng.choice([0.0, 0.0005, 0.003]))
    step = np.where((t // rng.integers(20, 80)) % 2 == 0, 0.0, 0.6)                   # steps and held poses
    cols.append(step + rng.normal(size=n) * 0.001 * (t > n / 2))
    cols.append(np.clip(cols[1] - 0.02, 0.0, 1.0))                                   # clipped at 0 (capture)
    cols.append(np.full(n, 0.25))
    return t, np.column_stack(cols)


@pytest.mark.parametrize("seed", range(4))
def test_random_curves_within_tolerance_at_every_frame(seed):
    rng = np.random.default_rng(900 + seed)
    frames, dense = _random_curves(rng, int(rng.integers(300, 800)))
    for tol in (0.002, 0.02):
        _check(frames, dense, tol, reduce_keys_bezier_curves(frames, dense, tol))


def test_live_link_take_within_tolerance_at_every_frame():
    stream = read_live_link_csv(CSV)
    _, w = resample(stream.times, stream.weights, 30.0, 1.0)
    dense = np.clip(np.tile(w, (2, 1)), 0.0, 1.0)
    frames = np.arange(1.0, dense.shape[0] + 1.0)
    for tol in (0.002, 0.01):
        _check(frames, dense, tol, reduce_keys_bezier_curves(frames, dense, tol))
