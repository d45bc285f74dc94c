"""Synthetic rigs shared by the benchmarks and the tests that check the same claims (not shipped).

Numpy only, so the core test tier (no Blender) can load it.

- :func:`redundant_rig`: random Gaussian bumps (rank 66 of 124), for the core tier (no Blender, no assets);
- :func:`redundant_head_rig`: the same kind of redundancy built on a real head's ARKit keys (e.g. FBHead read
  through the bridge): a 124-key avatar face like the ones VRoid/VRM users have, rank ≈ 90.
"""
import numpy as np

#: Relative tolerance of :func:`numerical_rank`: singular values ≤ this × the largest count as zero.  Exact
#: duplicates, scaled copies and empty keys leave singular values at rounding level (≲ 1e-15 relative); the
#: near-duplicates' and visemes' independent parts are ≳ 1e-4 relative on FBHead.
RANK_RTOL = 1e-9


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


def numerical_rank(B: np.ndarray, rtol: float = RANK_RTOL) -> int:
    """Singular values of ``B`` above ``rtol`` × the largest (:data:`RANK_RTOL`)."""
    s = np.linalg.svd(np.asarray(B, dtype=np.float64), compute_uv=False)
    return int(np.sum(s > rtol * s[0])) if s.size and s[0] > 0 else 0


def arkit_columns(delta_matrix: np.ndarray, key_names: list, channels: list) -> np.ndarray:
    """A head's deltas (3p, n) as columns in the order of a take's ``channels`` (names matched case-insensitively;
    a channel the head has no key for is an empty column, e.g. FBHead's missing ``TongueOut``): (3p, len(channels))."""
    index = {name.lower(): j for j, name in enumerate(key_names)}
    D = np.asarray(delta_matrix, dtype=np.float64)
    return np.column_stack([D[:, index[c.lower()]] if c.lower() in index else np.zeros(D.shape[0])
                            for c in channels])


def smooth_field(positions: np.ndarray, rng: np.random.Generator, waves: int = 3) -> np.ndarray:
    """A smooth scalar field in [−1, 1] over the vertices (p,): the mean of ``waves`` plane waves of random
    direction, phase and 0.5–1.5 cycles per bounding-box diagonal."""
    P = np.asarray(positions, dtype=np.float64)
    lo, hi = P.min(0), P.max(0)
    U = (P - 0.5 * (lo + hi)) / max(float(np.linalg.norm(hi - lo)), 1e-300)
    field = np.zeros(P.shape[0])
    for _ in range(waves):
        a = rng.normal(size=3)
        a *= rng.uniform(0.5, 1.5) / np.linalg.norm(a)
        field += np.cos(2 * np.pi * (U @ a) + rng.uniform(0, 2 * np.pi))
    return field / waves


def redundant_head_rig(B0: np.ndarray, positions: np.ndarray, names: list, seed: int = 0, duplicates: int = 16,
                       scaled: int = 10, near: int = 24, visemes: int = 15, total: int = 124,
                       near_amplitude: float = 0.05, viseme_amplitude: float = 0.3) -> dict:
    """A redundant avatar face built on a real head's ARKit keys (like a VRoid/VRM face: ARKit keys plus vendor
    expression keys that repeat them, visemes and empty targets).

    Columns, in order: the ARKit keys ``B0`` as given (an ARKit name the head lacks is an empty column there);
    ``duplicates`` exact copies of ARKit keys; ``scaled`` copies times c ∈ [0.5, 2] (c ∉ [0.9, 1.1]);
    ``near`` near-duplicates ``δ_k ⊙ (1 + a φ(x))`` (each vertex's offset times a smooth field φ ∈ [−1, 1] of the
    vertex positions, a = ``near_amplitude``: geometrically independent, nearly parallel); ``visemes`` mixes of
    3–5 mouth/jaw keys (Dirichlet weights × 1.5) times ``(1 + a φ(x))``, a = ``viseme_amplitude``, each with its
    own field (independent of the keys and of each other); then empty keys up to ``total``.  Each vendor copy
    repeats a different non-empty ARKit key (seeded choice).  Numerical rank (:func:`numerical_rank`):
    non-empty ARKit keys + near + visemes (FBHead: 51 + 24 + 15 = 90 of 124).

    Parameters
    ----------
    B0 : ndarray (3p, k)
        The head's ARKit deltas, rows x0, y0, z0, x1, …; empty columns allowed.
    positions : ndarray (p, 3)
        The head's neutral vertex positions (for the smooth fields).
    names : list of str (k,)
        ARKit names of the columns of ``B0``.
    seed : int

    Returns
    -------
    dict
        ``B`` (3p, total); ``names`` (total,); ``kind`` (total,) of ``arkit``, ``duplicate``, ``scaled``, ``near``,
        ``viseme``, ``empty``; ``of`` int (total,): the ARKit column a copy repeats (its own index for ARKit keys,
        −1 for visemes and added empty keys); ``factor`` (total,): the scaled copies' c (1 elsewhere);
        ``rank``: :func:`numerical_rank` of ``B``; ``rank_rtol``.
    """
    B0 = np.asarray(B0, dtype=np.float64)
    P = np.asarray(positions, dtype=np.float64)
    k = B0.shape[1]
    if B0.shape[0] != 3 * P.shape[0] or len(names) != k:
        raise ValueError(f"B0 {B0.shape}, positions {P.shape} and {len(names)} names do not match")
    rng = np.random.default_rng(seed)
    live = np.flatnonzero(np.abs(B0).max(axis=0) > 0)
    if live.size < duplicates + scaled + near:
        raise ValueError(f"{live.size} non-empty ARKit keys; {duplicates + scaled + near} copies asked for")
    pick = rng.permutation(live)
    cols, out_names = [B0[:, j] for j in range(k)], list(names)
    kind, of, factor = ["arkit" if j in live else "empty" for j in range(k)], list(range(k)), [1.0] * k

    def add(col, name, what, src=-1, c=1.0):
        cols.append(col)
        out_names.append(name)
        kind.append(what)
        of.append(int(src))
        factor.append(float(c))
    for j in pick[:duplicates]:
        add(B0[:, j].copy(), f"{names[j]}_vendor", "duplicate", j)
    for j in pick[duplicates:duplicates + scaled]:
        c = rng.uniform(0.5, 0.9) if rng.uniform() < 0.5 else rng.uniform(1.1, 2.0)
        add(B0[:, j] * c, f"{names[j]}_x{c:.2f}", "scaled", j, c)
    for j in pick[duplicates + scaled:duplicates + scaled + near]:
        field = np.repeat(1.0 + near_amplitude * smooth_field(P, rng), 3)
        add(B0[:, j] * field, f"{names[j]}_near", "near", j)
    mouth = [j for j in live if any(t in names[j].lower() for t in ("mouth", "jaw"))]
    for v in range(visemes):
        keys = rng.choice(mouth, size=int(rng.integers(3, 6)), replace=False)
        mix = B0[:, keys] @ (1.5 * rng.dirichlet(np.ones(keys.size)))
        add(mix * np.repeat(1.0 + viseme_amplitude * smooth_field(P, rng), 3), f"viseme_{v:02d}", "viseme")
    for e in range(total - len(cols)):
        add(np.zeros(B0.shape[0]), f"empty_{e:02d}", "empty")
    if len(cols) != total:
        raise ValueError(f"{len(cols)} keys built, more than total={total}")
    B = np.column_stack(cols)
    return {"B": B, "names": out_names, "kind": np.array(kind), "of": np.array(of), "factor": np.array(factor),
            "rank": numerical_rank(B), "rank_rtol": RANK_RTOL}
