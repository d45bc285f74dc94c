"""Key reduction of a 10-minute take (#24): 36,000 frames of the shipped Live Link Face take, the reduced curves
evaluated independently (``scipy.interpolate.CubicHermiteSpline``, what Blender evaluates for keys with aligned
handles at a third of each segment) at every frame against the dense samples, at the default stage-1 span and a
short one."""
import os

import numpy as np
import pytest
from scipy.interpolate import CubicHermiteSpline

from core.keyreduce import _MAX_SPAN, reduce_keys_bezier_curves
from core.retarget.capture import read_live_link_csv, resample

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CSV = os.path.join(ROOT, "assets", "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")
TOL = 0.01


def _take(count, columns):
    stream = read_live_link_csv(CSV)
    _, w = resample(stream.times, stream.weights, 30.0, 1.0)
    w = np.tile(w, (-(-count // w.shape[0]), 1))[:count]
    return np.arange(1.0, count + 1.0), np.clip(w[:, columns], 0, 1)


def _worst(frames, dense, keys):
    worst = 0.0
    for j, (idx, kv, km) in enumerate(keys):
        assert idx[0] == 0 and idx[-1] == frames.size - 1 and np.all(np.diff(idx) > 0)
        curve = CubicHermiteSpline(frames[idx], kv, km)(frames)
        worst = max(worst, float(np.abs(curve - dense[:, j]).max()))
    return worst


@pytest.mark.slow
def test_ten_minute_take_every_frame_within_tolerance_and_few_keys():
    frames, dense = _take(36000, [1, 9, 14, 18, 25, 33, 44, 50])
    keys = reduce_keys_bezier_curves(frames, dense, TOL)
    assert _worst(frames, dense, keys) <= TOL
    total = sum(k[0].size for k in keys)
    assert total < 0.10 * dense.size
    short_span = reduce_keys_bezier_curves(frames, dense, TOL, max_span=_MAX_SPAN // 4)
    assert _worst(frames, dense, short_span) <= TOL
