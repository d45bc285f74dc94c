"""Stage 1 of key reduction on long takes (#24): starts that can no longer have a valid segment leave the search
as the span grows, and blocks of curves run on threads.  Both must leave the result exactly as it was: compared
with the general path's unpruned search and with one thread, on the shipped Live Link Face take and random
curves; the pruning's effect is counted (segments tested), not timed; a cancel from the progress callback stops
the threads."""
import os
import threading

import numpy as np
import pytest

from core import keyreduce
from core.keyreduce import _valid_window, curve_slopes, reduce_keys_bezier_curves
from core.progress import Cancelled
from test_keyreduce_blocks import _random_curves

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CSV = os.path.join(ROOT, "assets", "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")


def _take(count, curves):
    from core.retarget.capture import read_live_link_csv, resample
    stream = read_live_link_csv(CSV)
    frames, w = resample(stream.times, stream.weights, 30.0, 1.0)
    w = np.tile(w, (-(-count // w.shape[0]), 1))[:count]
    return frames[0] + np.arange(count, dtype=np.float64), np.ascontiguousarray(np.clip(w[:, curves], 0, 1).T)


def _random(seed, n=700, count=6):
    """Smooth random curves with noise and held plateaus (``test_keyreduce_blocks``'s), half-frame steps, (c, f)."""
    V = _random_curves(np.random.default_rng(seed), n, count)
    return np.arange(n, dtype=np.float64) * 0.5, np.ascontiguousarray(V.T)


def _both(t, V, tol, span):
    """The pruned uniform search and the general path's unpruned one (told the steps are uneven)."""
    M = np.vstack([curve_slopes(t, v) for v in V])
    return _valid_window(t, V, M, tol, span, True), _valid_window(t, V, M, tol, span, False)


@pytest.mark.parametrize("tol", [0.002, 0.01, 0.05])
def test_pruned_search_equals_the_unpruned_one_on_the_live_link_take(tol):
    t, V = _take(1200, [0, 3, 9, 14, 17, 21, 24, 25, 33, 40, 44, 47, 50])
    pruned, full = _both(t, V, tol, 128)
    np.testing.assert_array_equal(pruned, full)
    assert full[:, :, 40:].any()                                      # long valid segments exist


@pytest.mark.parametrize("seed", range(4))
def test_pruned_search_equals_the_unpruned_one_on_random_curves(seed):
    t, V = _random(seed)
    for tol in (0.001, 0.005):
        pruned, full = _both(t, V, tol, 90)
        np.testing.assert_array_equal(pruned, full)


def test_pruned_search_for_the_first_starts_of_a_window():
    t, V = _random(9, n=400)
    M = np.vstack([curve_slopes(t, v) for v in V])
    part = _valid_window(t, V, M, 0.004, 60, True, 250)
    assert part.shape == (V.shape[0], 250, 61)
    np.testing.assert_array_equal(part, _valid_window(t, V, M, 0.004, 60, False)[:, :250])


def test_starts_leave_the_search_once_no_longer_segment_can_be_valid(monkeypatch):
    """Counted: the (start, span) pairs whose segment is tested are a fraction of all of them, and no start
    leaves while a longer valid segment from it exists (the result above is exact)."""
    t, V = _take(3000, list(range(51)))
    tested = []
    inner = keyreduce._uniform_tests

    def count(flat, st, *args):
        tested.append(int(np.count_nonzero(st.live)))
        return inner(flat, st, *args)
    monkeypatch.setattr(keyreduce, "_uniform_tests", count)
    M = np.vstack([curve_slopes(t, v) for v in V])
    ok = keyreduce._valid_segments(t, V, M, 0.01, 128)
    moving = np.count_nonzero(np.any(V != V[:, :1], axis=1))
    everything = moving * sum(t.size - d for d in range(2, 129))
    assert sum(tested) < 0.5 * everything                         # measured 0.40 on this take
    longest = np.where(ok.any(axis=2), ok.shape[2] - 1 - np.argmax(ok[:, :, ::-1], axis=2), 0)
    assert sum(tested) >= np.maximum(longest - 1, 0).sum()        # every start is tested up to its longest valid one


def test_threads_give_the_keys_of_one_thread(monkeypatch):
    t, V = _take(2400, [1, 9, 14, 18, 25, 33, 44, 50])
    monkeypatch.setattr(keyreduce, "_BLOCK_SAMPLES", 2 * 2400)      # four blocks of two curves
    many = reduce_keys_bezier_curves(t, V.T, 0.01)
    monkeypatch.setattr(keyreduce, "_MAX_WORKERS", 1)
    one = reduce_keys_bezier_curves(t, V.T, 0.01)
    for a, b in zip(many, one):
        for x, y in zip(a, b):
            np.testing.assert_array_equal(x, y)


def test_a_cancel_in_stage_one_stops_its_threads(monkeypatch):
    t, V = _take(2400, list(range(0, 51, 3)))
    monkeypatch.setattr(keyreduce, "_BLOCK_SAMPLES", 2400)        # one curve per block: many blocks
    monkeypatch.setattr(keyreduce, "_MAX_WORKERS", 2)
    calls = []

    def progress(fraction):
        calls.append(fraction)
        if len(calls) == 2:
            raise Cancelled()
    before = threading.active_count()
    with pytest.raises(Cancelled):
        reduce_keys_bezier_curves(t, V.T, 0.01, progress=progress)
    assert threading.active_count() == before
    assert not any(th.name.startswith("shapespace-keyreduce") for th in threading.enumerate())
