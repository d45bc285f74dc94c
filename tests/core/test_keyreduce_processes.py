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


_PARENT = """
import os, signal, sys, time
sys.path.insert(0, {root!r})
import numpy as np
from core.workers import ChildCall
signal.signal(signal.SIGPIPE, signal.SIG_DFL)       # as an embedded Python may leave it
child = ChildCall("keyreduce", "reduce_keys_bezier_curves", (np.arange({frames}.0), np.random.default_rng(0).normal(
    size=({frames}, {curves})).cumsum(axis=0) * 0.01, 1e-4))
print(child._proc.pid, flush=True)
{then}
"""


def _parent(tmp_path, curves, then, frames=4000):
    import os
    import subprocess
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    return subprocess.run([sys.executable, "-c", _PARENT.format(root=root, curves=curves, then=then, frames=frames)],
                          capture_output=True, text=True, timeout=120, cwd=tmp_path)


@pytest.mark.skipif(not hasattr(__import__("signal"), "SIGPIPE"), reason="no SIGPIPE on this platform")
def test_a_child_that_dies_early_is_no_signal_to_the_parent(tmp_path):
    """A large payload, the child killed at once: the write fails in the writing thread, SIGPIPE at its default
    does not end the parent."""
    proc = _parent(tmp_path, 400, "child.stop()\nprint('alive', child.result())")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split()[-2:] == ["alive", "None"]


@pytest.mark.skipif(sys.platform == "win32", reason="reads /proc-style liveness with os.kill(pid, 0)")
def test_a_child_ends_when_its_parent_goes_away(tmp_path):
    import os
    import time
    proc = _parent(tmp_path, 60, "time.sleep(1.0)\nos._exit(0)", frames=30000)    # a job of a minute or more
    pid = int(proc.stdout.split()[0])
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return
        time.sleep(0.05)
    os.kill(pid, 9)
    pytest.fail("the child kept running after its parent exited")


def test_a_child_with_another_numpy_gives_up(monkeypatch):
    monkeypatch.setattr(np, "__file__", "/elsewhere/numpy/__init__.py")
    assert ChildCall("keyreduce", "curve_slopes", (np.arange(5.0), np.arange(5.0) ** 2)).result() is None


def test_curves_without_work_make_no_empty_group(monkeypatch, groups):
    t = np.arange(2000.0)
    V = np.column_stack([t * 0.5, t * 0.25, np.sin(t / 30.0)])         # two exact ramps: no curvature at all
    parts = keyreduce._process_groups(np.ascontiguousarray(V.T), 0.01)
    assert all(p.size and p.dtype.kind == "i" for p in parts)
    _same(keyreduce.reduce_keys_bezier_curves(t, V, 0.01), _one_process(t, V, monkeypatch))
    ramps = keyreduce._process_groups(np.ascontiguousarray(V[:, :2].T), 0.01)
    assert sorted(np.concatenate(ramps).tolist()) == [0, 1] and all(p.size for p in ramps)


def test_stage_one_threads_stay_within_the_cap(monkeypatch):
    seen = []
    real = keyreduce.ThreadPoolExecutor

    def pool(max_workers, **kwargs):
        seen.append(max_workers)
        return real(max_workers=max_workers, **kwargs)
    monkeypatch.setattr(keyreduce, "ThreadPoolExecutor", pool)
    monkeypatch.setattr(keyreduce, "child_cpus", lambda: 16)
    monkeypatch.setattr(keyreduce, "_MAX_WORKERS", 1)
    monkeypatch.setattr(keyreduce, "_BLOCK_SAMPLES", 2000)
    t, V = _take()
    keyreduce.reduce_keys_bezier_curves(t[:2000], V[:2000], 0.01)
    assert seen and max(seen) == 1


def test_unusable_child_results_are_recognised():
    good = [(np.array([0, 5, 9]), np.zeros(3), np.zeros(3))]
    assert keyreduce._usable(good, 1, 10)
    assert not keyreduce._usable([(np.array([0, 5, 9]), np.array(["a", "b", "c"]), np.zeros(3))], 1, 10)
    assert not keyreduce._usable([(np.array([0.0, 5.0, 9.0]), np.zeros(3), np.zeros(3))], 1, 10)
    assert not keyreduce._usable([(np.array([0, 5, 9]), np.array([0.0, np.nan, 0.0]), np.zeros(3))], 1, 10)
    assert not keyreduce._usable(good, 2, 10) and not keyreduce._usable(None, 1, 10)


def test_a_one_row_product_rounds_as_in_a_block():
    rng = np.random.default_rng(3)
    P, Q = rng.normal(size=(300, 4)), rng.normal(size=(4, 37))
    block = keyreduce._products(P, Q)
    assert all(np.array_equal(keyreduce._products(P[i:i + 1], Q), block[i:i + 1]) for i in range(300))
