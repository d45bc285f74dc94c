"""Key reduction split into lanes and chunks (#11, long takes): stage 2's sweeps run as lanes of keys that hand
over where they meet, stage 1 in chunks of starts.  Both must give exactly the keys of the sequential
computation: compared here against a reference copy of the sequential sweep (all curves in lock step, one test
per curve and step), on random curves and on the shipped Live Link Face take, for many lane lengths, plus a
brute-force check that every sample is within the tolerance of the Hermite Blender evaluates."""
import os

import numpy as np
import pytest

from core import keyreduce
from core.keyreduce import _absorb_batch, _valid_segments, curve_slopes, hermite, reduce_keys_bezier_curves

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CSV = os.path.join(ROOT, "assets", "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")


def _sequential_absorb(t, V, idx, kv, km, tol, max_sweeps=4):
    """Reference: stage 2 as it was before the lanes (every curve sweeps its keys left to right, one
    absorption test per curve and step, until a sweep drops none; a test is skipped when the keys it reads
    are those of its last failure)."""
    C = len(idx)
    p, sweep, changed = [1] * C, [0] * C, [False] * C
    failed = [{} for _ in range(C)]
    active = list(range(C))
    while active:
        tests, sigs, still = [], [], []
        for c in active:
            ik, vk, mk = idx[c], kv[c], km[c]
            while True:
                q = p[c]
                if q >= len(ik) - 1:
                    if not changed[c] or sweep[c] + 1 >= max_sweeps:
                        q = None
                        break
                    sweep[c], changed[c], p[c] = sweep[c] + 1, False, 1
                    continue
                a, b = max(q - 2, 0), min(q + 2, len(ik) - 1)
                sig = (ik[a], ik[q - 1], ik[q + 1], ik[b], vk[a], mk[a], vk[b], mk[b])
                if failed[c].get(ik[q]) != sig:
                    break
                p[c] += 1
            if q is not None:
                still.append(c)
                tests.append((c, q, a, b))
                sigs.append(sig)
        active = still
        if not tests:
            return
        for (c, q, _, _), sig, x in zip(tests, sigs, _absorb_batch(t, V, tests, idx, kv, km, tol)):
            if x is None:
                failed[c][idx[c][q]] = sig
                p[c] += 1
            else:
                kv[c][q - 1], km[c][q - 1], kv[c][q + 1], km[c][q + 1] = x
                del idx[c][q], kv[c][q], km[c][q]
                changed[c] = True


def _reference(t, V, tol):
    """Stage 1 (unchanged, ``refine=False``) then the sequential stage 2 above."""
    stage1 = reduce_keys_bezier_curves(t, V, tol, refine=False)
    idx = [k[0].tolist() for k in stage1]
    kv = [k[1].tolist() for k in stage1]
    km = [k[2].tolist() for k in stage1]
    _sequential_absorb(t, np.ascontiguousarray(V.T), idx, kv, km, tol)
    return idx, kv, km


def _assert_same(keys, ref, t, V, tol):
    idx, kv, km = ref
    assert len(keys) == V.shape[1]
    for j, (i, a, b) in enumerate(keys):
        assert i.tolist() == idx[j]
        assert a.tolist() == kv[j]                       # bit for bit: the same tests in the same order
        assert b.tolist() == km[j]
        assert np.abs(hermite(t[i], a, b, t) - V[:, j]).max() <= tol


def _random_curves(rng, n, count):
    cols = []
    for k in range(count):
        w = int(rng.choice([5, 9, 21, 41, 81]))
        v = np.convolve(rng.normal(size=n + 2 * w), np.hanning(w), "same")[w:n + w] * rng.uniform(0.02, 0.2)
        v += rng.normal(size=n) * rng.choice([0.0, 0.001, 0.004])
        if k % 4 == 3:
            lo = int(rng.integers(0, n // 2))
            v[lo:lo + n // 4] = v[lo]                               # a held plateau
        cols.append(v)
    return np.column_stack(cols)


def _tiled_take(count, curves):
    from core.retarget.capture import read_live_link_csv, resample
    stream = read_live_link_csv(CSV)
    frames, w = resample(stream.times, stream.weights, 30.0, 1.0)
    w = np.tile(w, (-(-count // w.shape[0]), 1))[:count]
    return frames[0] + np.arange(count, dtype=np.float64), np.clip(w[:, curves], 0, 1)


@pytest.mark.parametrize("lane", [2, 3, 8, 32, 10 ** 6])
@pytest.mark.parametrize("seed", range(3))
def test_lanes_give_the_sequential_keys_on_random_curves(monkeypatch, seed, lane):
    rng = np.random.default_rng(300 + seed)
    n = int(rng.integers(200, 900))
    t = np.arange(1.0, n + 1.0) if seed != 2 else np.cumsum(rng.uniform(0.5, 1.5, n))    # also uneven times
    V = _random_curves(rng, n, 6)
    tol = float(rng.choice([0.002, 0.005, 0.01]))
    ref = _reference(t, V, tol)
    monkeypatch.setattr(keyreduce, "_LANE_KEYS", lane)
    _assert_same(reduce_keys_bezier_curves(t, V, tol), ref, t, V, tol)


@pytest.mark.slow
@pytest.mark.parametrize("lane", [4, 16, 128])
def test_lanes_give_the_sequential_keys_on_the_live_link_take(monkeypatch, lane):
    t, V = _tiled_take(2600, [0, 3, 9, 17, 21, 24, 33, 40, 47, 50])
    ref = _reference(t, V, 0.01)
    monkeypatch.setattr(keyreduce, "_LANE_KEYS", lane)
    keys = reduce_keys_bezier_curves(t, V, 0.01)
    _assert_same(keys, ref, t, V, 0.01)
    assert sum(k[0].size for k in keys) == sum(len(i) for i in ref[0])


def test_lanes_handle_tiny_and_flat_curves(monkeypatch):
    monkeypatch.setattr(keyreduce, "_LANE_KEYS", 2)
    t = np.arange(1.0, 7.0)
    V = np.column_stack([np.zeros(6), np.linspace(0, 1, 6) ** 2, [0, 1, 0, 1, 0, 1.0], np.full(6, 0.3)])
    ref = _reference(t, V, 0.01)
    _assert_same(reduce_keys_bezier_curves(t, V, 0.01), ref, t, V, 0.01)
    for n in (3, 4):
        _assert_same(reduce_keys_bezier_curves(t[:n], V[:n], 0.01), _reference(t[:n], V[:n], 0.01), t[:n], V[:n],
                     0.01)
    for n in (1, 2):
        assert all(k[0].tolist() == list(range(n)) for k in reduce_keys_bezier_curves(t[:n], V[:n], 0.01))


@pytest.mark.slow
@pytest.mark.parametrize("uniform", [True, False])
def test_stage_one_in_chunks_equals_one_piece(monkeypatch, uniform):
    rng = np.random.default_rng(11)
    n = 700
    t = np.arange(n, dtype=float) if uniform else np.cumsum(rng.uniform(0.5, 1.5, n))
    V = _random_curves(rng, n, 4).T.copy()
    M = np.vstack([curve_slopes(t, v) for v in V])
    whole = _valid_segments(t, V, M, 0.004, 60)
    for chunk in (1, 37, 256):
        monkeypatch.setattr(keyreduce, "_CHUNK_STARTS", chunk)
        np.testing.assert_array_equal(_valid_segments(t, V, M, 0.004, 60), whole)


@pytest.mark.slow
def test_long_take_in_chunks_and_lanes_keeps_the_tolerance_and_the_key_count(monkeypatch):
    """6,000 frames (chunked stage 1 at the default chunk size, many lanes): the sequential keys exactly."""
    t, V = _tiled_take(6000, [1, 14, 25, 44])
    ref = _reference(t, V, 0.01)
    monkeypatch.setattr(keyreduce, "_CHUNK_STARTS", 10 ** 7)                 # stage 1 in one piece
    whole = reduce_keys_bezier_curves(t, V, 0.01, refine=False)
    monkeypatch.undo()
    chunked = reduce_keys_bezier_curves(t, V, 0.01, refine=False)
    for a, b in zip(whole, chunked):
        for x, y in zip(a, b):
            np.testing.assert_array_equal(x, y)
    _assert_same(reduce_keys_bezier_curves(t, V, 0.01), ref, t, V, 0.01)


def _shortest_reference(ok, extra):
    """Reference for stage 1's shortest path: a plain dynamic programme in sample order over every valid segment
    (the graph only goes forward), each sample's previous key the earliest start one segment nearer the first."""
    n = ok.shape[0]
    into = [[] for _ in range(n)]
    for i, d in zip(*np.nonzero(ok)):
        into[i + d].append(int(i))
    for i, j in zip(*extra):
        into[int(j)].append(int(i))
    dist, prev = [0] + [None] * (n - 1), [-1] * n
    for j in range(1, n):
        best = min(dist[i] for i in into[j])
        dist[j] = best + 1
        prev[j] = min(i for i in into[j] if dist[i] == best)
    keys = [n - 1]
    while keys[-1] > 0:
        keys.append(prev[keys[-1]])
    return keys[::-1], dist


def _segment_table(rng, n, span, density):
    """A random stage-1 table ``ok`` (n, span + 1): every one-sample step valid, none past the end."""
    ok = rng.random((n, span + 1)) < rng.uniform(0.05, density)
    ok[:, 0] = False
    ok[:, 1] = True
    ok[np.arange(n)[:, None] + np.arange(span + 1) >= n] = False
    return ok


@pytest.mark.parametrize("seed", range(4))
def test_fewest_keys_is_the_shortest_path_with_the_earliest_previous_key(seed):
    """Breadth-first depths by pointer doubling and the flat-pose segments inserted into the CSR rows: the same
    distances and keys as a plain dynamic programme, on random segment tables with long extra segments."""
    rng = np.random.default_rng(40 + seed)
    n, span = int(rng.integers(50, 400)), int(rng.integers(2, 30))
    ok = _segment_table(rng, n, span, 0.6)
    starts = np.sort(rng.choice(n - span - 1, size=int(rng.integers(0, 4)), replace=False))
    ends = np.minimum(starts + span + 1 + rng.integers(0, 40, starts.size), n - 1)
    extra = (starts, ends)
    keys, dist = _shortest_reference(ok, extra)
    assert keyreduce._fewest_keys(ok, extra) == keys
    assert keyreduce._fewest_keys(ok, (np.array([], int), np.array([], int))) == _shortest_reference(ok, ([], []))[0]
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import breadth_first_order
    i, d = np.nonzero(ok)
    graph = csr_matrix((np.ones(i.size + starts.size), (np.r_[i, starts], np.r_[i + d, ends])), shape=(n, n))
    pred = breadth_first_order(graph, 0, directed=True, return_predecessors=True)[1]
    np.testing.assert_array_equal(keyreduce._bfs_depth(pred), dist)


@pytest.mark.parametrize("seed", range(4))
def test_fewest_keys_with_extra_segments_sharing_starts_and_ends(seed):
    """Nearly held poses add extra segments that share a start or an end with an exactly held one inside them
    (:func:`keyreduce._held_spans`): several per start, sorted by start then end, and several into one sample
    (the earliest start wins): the plain dynamic programme's keys."""
    rng = np.random.default_rng(80 + seed)
    n, span = int(rng.integers(120, 400)), int(rng.integers(2, 20))
    ok = _segment_table(rng, n, span, 0.4)
    pairs = set()
    for _ in range(int(rng.integers(2, 8))):
        i = int(rng.integers(0, n - span - 2))
        j = min(i + span + 1 + int(rng.integers(0, 60)), n - 1)
        pairs |= {(i, j), (i, min(j + int(rng.integers(1, 30)), n - 1)), (max(i - int(rng.integers(1, 9)), 0), j)}
    pairs = sorted(p for p in pairs if p[1] - p[0] > span)
    extra = (np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs]))
    assert keyreduce._fewest_keys(ok, extra) == _shortest_reference(ok, extra)[0]
