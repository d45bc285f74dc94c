"""Key reduction across processes (#24): groups of curves reduced in child Python processes
(``core.workers.ChildCall``) give exactly the keys of one process; a child that cannot start, fails or returns
garbage is replaced by the same work here; a cancel kills the children."""
import sys

import numpy as np
import pytest

from core import keyreduce, workers
from core.progress import Cancelled
from core.workers import ChildCall
from test_keyreduce_blocks import _tiled_take


def _take():
    t, V = _tiled_take(3000, [0, 1, 9, 14, 18, 25, 33, 44, 50])
    V[:, 1] = 0.25                                                    # a constant curve among them
    return t, V


def _same(a, b):
    assert len(a) == len(b)
    for x, y in zip(a, b):
        for u, v in zip(x, y):
            np.testing.assert_array_equal(u, v)


@pytest.fixture
def groups(monkeypatch):
    """Spread any take over three processes (this one and two children)."""
    monkeypatch.setattr(keyreduce, "_CHILD_SAMPLES", 1)
    monkeypatch.setattr(keyreduce, "child_cpus", lambda: 3)


def _one_process(t, V, monkeypatch):
    with monkeypatch.context() as m:
        m.setattr(keyreduce, "_CHILD_SAMPLES", 10 ** 12)
        return keyreduce.reduce_keys_bezier_curves(t, V, 0.01)


def test_children_give_the_keys_of_one_process(monkeypatch, groups):
    t, V = _take()
    results = []
    real = ChildCall.result

    def spy(self, *args):
        got = real(self, *args)
        results.append(got)
        return got
    monkeypatch.setattr(ChildCall, "result", spy)
    _same(keyreduce.reduce_keys_bezier_curves(t, V, 0.01), _one_process(t, V, monkeypatch))
    assert len(results) == 2 and all(isinstance(r, list) and r for r in results)      # the children did the work


@pytest.mark.parametrize("broken", ["no interpreter", "fails", "garbage"])
def test_a_child_without_a_usable_result_is_replaced_here(monkeypatch, groups, broken):
    t, V = _take()
    if broken == "no interpreter":
        monkeypatch.setattr(sys, "executable", "")
    elif broken == "fails":
        monkeypatch.setattr(workers, "_BOOT", "raise SystemExit(3)")
    else:
        monkeypatch.setattr(ChildCall, "result", lambda self, *a: [(np.arange(3), np.zeros(3), np.zeros(2))])
    _same(keyreduce.reduce_keys_bezier_curves(t, V, 0.01), _one_process(t, V, monkeypatch))


def test_groups_balance_the_keys_and_cover_every_curve(monkeypatch):
    """The groups split the first stage's keys (which set the work) about evenly, from a proxy known before it."""
    monkeypatch.setattr(keyreduce, "child_cpus", lambda: 2)
    t, V = _tiled_take(36000, list(range(51)))
    parts = keyreduce._process_groups(np.ascontiguousarray(V.T), 0.01)
    assert len(parts) == 2
    assert sorted(np.concatenate(parts).tolist()) == list(range(51))
    keys = np.array([k[0].size for k in keyreduce.reduce_keys_bezier_curves(t, V, 0.01, refine=False)])
    share = [keys[p].sum() / keys.sum() for p in parts]
    assert min(share) > 0.45                                          # measured 0.49
    monkeypatch.setattr(keyreduce, "child_cpus", lambda: 1)
    assert len(keyreduce._process_groups(np.ascontiguousarray(V.T), 0.01)) == 1


def test_a_cancel_while_waiting_kills_the_child():
    t, V = _tiled_take(6000, list(range(20)))
    V = np.ascontiguousarray(V.T)
    M = np.vstack([keyreduce.curve_slopes(t, v) for v in V])
    child = ChildCall("keyreduce", "_reduce_group", (t, V, M, 0.01, 128, True))

    def cancel(fraction):
        raise Cancelled()
    with pytest.raises(Cancelled):
        child.result(cancel)
    assert child._proc.poll() is not None                             # killed and reaped
    child.stop()                                                      # idempotent


def test_a_child_call_returns_the_function_result_or_none():
    assert ChildCall("keyreduce", "curve_slopes", (np.arange(5.0), np.arange(5.0) ** 2)).result().tolist() == [
        1.0, 2.0, 4.0, 6.0, 7.0]
    assert ChildCall("keyreduce", "no_such_function", ()).result() is None
    assert ChildCall("no_such_module", "f", ()).result() is None
