"""The example benchmark's ceilings (tools/bench_examples.py) are what they claim: each oracle reproduces a set of
held-out keys made exactly by its own family (an analytic answer: error 0), the richer family is never worse
than the gain it contains, and each equals an independent least-squares solve (NumPy's ``lstsq``) where it
has a closed form."""
import importlib.util
import os
import sys

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
TOOLS = os.path.join(ROOT, "tools")


@pytest.fixture(scope="module")
def bench():
    """tools/bench_examples.py, imported with tools/ on the path (its sibling modules) for this module only."""
    mp = pytest.MonkeyPatch()
    mp.syspath_prepend(TOOLS)
    spec = importlib.util.spec_from_file_location("shapespace_bench_examples", os.path.join(TOOLS, "bench_examples.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    yield module
    mp.undo()
    for name in ("bench_transfer_v2", "bench_support", "env"):
        if os.path.dirname(getattr(sys.modules.get(name), "__file__", None) or "") == TOOLS:
            del sys.modules[name]


def _rig(seed=0, k=9, n=40):
    """(transferred deltas (k, n, 3) under source names, authored names, source names, held-out names)."""
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(k, n, 3))
    X[:, :3] = 0.0                      # vertices no key moves (a still part)
    names = [f"key{i}" for i in range(k)]
    return X, names, list(reversed(names)), names[2:]


def _authored_like(X, names, src_names, fn):
    """Authored deltas in ``names`` order made from the transferred ones of the same name by ``fn``."""
    return np.stack([fn(i, X[src_names.index(n)]) for i, n in enumerate(names)])


def test_each_oracle_reproduces_keys_made_by_its_own_family(bench):
    X, TN, SN, held = _rig()
    rng = np.random.default_rng(1)
    s, g = rng.uniform(0.3, 2.0, len(TN)), rng.uniform(0.2, 3.0, X.shape[1])
    DT = X[[TN.index(n) for n in SN]]
    A = _authored_like(DT, TN, SN, lambda i, x: s[i] * g[:, None] * x)
    assert bench.oracle_key_vertex_gain(DT, A, TN, SN, held, sweeps=400) < 1e-6
    assert bench.oracle_gain(DT, A, TN, SN, held) > 0.05          # a per-key scale is not a per-vertex gain
    L = rng.normal(size=(X.shape[1], 3, 3))
    A = _authored_like(DT, TN, SN, lambda i, x: np.einsum("vij,vj->vi", L, x))
    assert bench.oracle_linear(DT, A, TN, SN, held) < 1e-9
    assert bench.oracle_gain(DT, A, TN, SN, held) > 0.1


def test_richer_families_are_never_worse_than_the_gain(bench):
    for seed in range(5):
        X, TN, SN, held = _rig(seed)
        A = np.random.default_rng(seed + 10).normal(size=X.shape)
        gain = bench.oracle_gain(X, A, TN, SN, held)
        assert bench.oracle_key_vertex_gain(X, A, TN, SN, held) <= gain + 1e-12
        assert bench.oracle_linear(X, A, TN, SN, held) <= gain + 1e-12


def test_gain_and_linear_oracles_equal_independent_least_squares(bench):
    X, TN, SN, held = _rig(3)
    A = np.random.default_rng(4).normal(size=X.shape)
    Ah = np.stack([A[TN.index(n)] for n in held])
    Xh = np.stack([X[SN.index(n)] for n in held])
    gain_fit = np.zeros_like(Ah)
    linear_fit = np.zeros_like(Ah)
    for v in range(X.shape[1]):
        x, a = Xh[:, v].reshape(-1, 1), Ah[:, v].reshape(-1)
        gain_fit[:, v] = (x @ np.linalg.lstsq(x, a, rcond=None)[0]).reshape(-1, 3)
        L = np.linalg.lstsq(Xh[:, v], Ah[:, v], rcond=None)[0]       # rows: Xh L = Ah, i.e. L_v = Lᵀ
        linear_fit[:, v] = Xh[:, v] @ L
    norm = np.linalg.norm(Ah)
    assert bench.oracle_gain(X, A, TN, SN, held) == pytest.approx(np.linalg.norm(gain_fit - Ah) / norm, rel=1e-9)
    assert bench.oracle_linear(X, A, TN, SN, held) == pytest.approx(np.linalg.norm(linear_fit - Ah) / norm,
                                                                     rel=1e-9)
