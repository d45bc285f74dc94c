"""Synthetic rigs shared by the benchmarks and the tests that check the same claims (not shipped).

Numpy only, so the core test tier (no Blender) can load it.
"""
import numpy as np


def redundant_rig(seed: int = 0, m: int = 400) -> tuple:
    """52 local ARKit-like deltas, 20 exact duplicates, 16 scaled copies, 14 near duplicates, 15 visemes
    (mixes of mouth keys) and 7 empty targets: (B (3m, 124), source weights (131, 52), base (3m, 52))."""
    rng = np.random.default_rng(seed)
    P = rng.normal(size=(m, 3))
    centers = rng.normal(size=(52, 3))
    base = np.stack([np.exp(-np.sum((P - c) ** 2, 1) / 0.3)[:, None] * rng.normal(size=3) for c in centers], -1)
    base = base.reshape(3 * m, 52) * 0.05
    cols = [base[:, j] for j in range(52)]
    cols += [base[:, j].copy() for j in range(20)]
    cols += [base[:, j] * rng.uniform(0.5, 2.0) for j in range(20, 36)]
    cols += [base[:, j] + rng.normal(size=3 * m) * 1e-4 * np.abs(base[:, j]).max() for j in range(36, 50)]
    cols += [base[:, 20:40] @ rng.dirichlet(np.ones(20)) * 2 for _ in range(15)]
    cols += [np.zeros(3 * m)] * (124 - len(cols))
    W = np.clip(np.cumsum(rng.normal(size=(131, 52)) * 0.05, 0) % 1.0, 0, 1)
    return np.column_stack(cols), W, base
