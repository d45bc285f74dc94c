"""Example-guided transfer benchmark keys (issue #22 §5): every ordered pair of the four shared heads.

Per pair ``<src>_<dst>`` the plain transfer (:func:`bench_transfer_v2.transferred`: landmarks, registration,
deformation transfer, parts) is refined with 5 example keys of the target
(:func:`core.authoring.examples.refine_with_examples`) and scored on the target's OTHER authored keys (the
held-out keys: every key the target authored with a peak at least 5 % of its largest, the source has, and no
example uses), jointly over all their vertices, skin and parts together (the ``transfer_rel_energy``
definition of ``bench_transfer_v2``):

- ``transfer_rel_energy_examples5_<pair>``: ‖ΔT − ΔA‖ / ‖ΔA‖ of the refined held-out keys; each example is
  one authored key with weight 1 on the source shape of the same name;
- ``transfer_rel_energy_plain_heldout_<pair>``: the plain transfer on the same held-out keys;
- ``transfer_examples_heldout_worse_keys_<pair>``: held-out keys whose error the refinement increased;
- ``transfer_examples_heldout_not_worse_<pair>`` (and ``_combo_``, ``_approx_``): the refined held-out keys are
  jointly no further from the authored ones than the plain transfer (issue #22 §5: never worse);
- ``transfer_rel_energy_examples5_combo_<pair>`` and ``transfer_examples_combo_heldout_worse_keys_<pair>``: the
  same with each example a combination of two of the five keys, ``A_i + 0.5 A_(i+1)`` (cyclic), given with
  those weights — the held-out keys are the same;
- ``transfer_rel_energy_examples5_approx_<pair>`` and ``transfer_examples_approx_heldout_worse_keys_<pair>``: the
  combinations made with ``A_i + 0.7 A_(i+1)`` but given as ``1`` and ``0.5`` (approximate weights);
- ``transfer_rel_energy_oracle_gain_heldout_<pair>``: the ceiling of a per-vertex gain: the best gain per vertex
  fitted to the held-out keys themselves (least squares, in-sample) — what no refinement learnt from examples
  through a gain field can beat;
- ``transfer_rel_energy_oracle_key_gain_heldout_<pair>``: the same with a per-key scale times a per-vertex gain
  (the ceiling of every rescaling: a key's size included, which no one-key example states for another key);
- ``transfer_rel_energy_oracle_linear_heldout_<pair>``: the best per-vertex 3×3 linear map fitted to the
  held-out keys themselves (the ceiling of every per-vertex map of the transferred motion, direction included);
- ``transfer_examples_heldout_worst_ratio_<pair>``: the largest refined / plain error ratio of a held-out key;
- ``transfer_examples_residual_<pair>``: the largest relative residual of an example after refinement;
- ``transfer_examples_s_<pair>``: seconds of the refinement (one-hot examples).

The examples are :data:`EXAMPLES` — the first five of that list the target authored (peak ≥ 5 %) and the source
has.  ``quick`` computes the same keys (ICT pairs included; the whole suite takes a few minutes).
"""
from __future__ import annotations

import sys
import time

import numpy as np

import bench_transfer_v2 as v2

EXAMPLES = ("jawOpen", "mouthSmileLeft", "eyeBlinkLeft", "browInnerUp", "mouthFunnel", "mouthPucker", "jawLeft",
            "eyeLookOutLeft")
COMBO_WEIGHT = 0.5
APPROX_TRUE_WEIGHT = 0.7          # the "approximate weights" variant: made with this, given as COMBO_WEIGHT


def authored_keys(TD, TN, SN):
    """Names of the target's authored keys scored (peak ≥ 5 % of the largest, present on the source)."""
    peaks = np.abs(TD).reshape(len(TN), -1).max(axis=1)
    return [n for j, n in enumerate(TN) if n in SN and peaks[j] >= 0.05 * peaks.max()]


def example_set(keys, combo):
    """(example names, weights as {source name: weight} per example) of the first five :data:`EXAMPLES` in
    ``keys``; ``combo`` (a weight): example ``i`` is key ``i`` + ``combo`` × key ``i + 1`` (cyclic); 0: one key."""
    chosen = [n for n in EXAMPLES if n in keys][:5]
    if not combo:
        return chosen, [{n: 1.0} for n in chosen]
    m = len(chosen)
    return chosen, [{chosen[i]: 1.0, chosen[(i + 1) % m]: combo} for i in range(m)]


def _held(DT, TD, TN, SN, held):
    """(authored (k, n, 3), transferred (k, n, 3)) of the keys ``held``."""
    return np.stack([TD[TN.index(n)] for n in held]), np.stack([DT[SN.index(n)] for n in held])


def held_out_scores(DT, DR, TD, TN, SN, held):
    """(relative error of the plain keys, of the refined keys, number of keys made worse, the largest ratio of
    a key's refined error to its plain error) over ``held``."""
    A, X0 = _held(DT, TD, TN, SN, held)
    X1 = np.stack([DR[SN.index(n)] for n in held])
    e0 = np.linalg.norm((X0 - A).reshape(len(held), -1), axis=1)
    e1 = np.linalg.norm((X1 - A).reshape(len(held), -1), axis=1)
    norm = np.linalg.norm(A)
    ratio = float(np.max(e1 / np.where(e0 > 0, e0, 1.0)))
    return float(np.linalg.norm(e0) / norm), float(np.linalg.norm(e1) / norm), int((e1 > e0).sum()), ratio


def oracle_gain(DT, TD, TN, SN, held):
    """Relative error over ``held`` of the best per-vertex gain fitted to the held-out keys themselves."""
    A, X = _held(DT, TD, TN, SN, held)
    xx = np.einsum("kvi,kvi->v", X, X)
    g = np.einsum("kvi,kvi->v", A, X) / np.where(xx > 0, xx, 1.0)
    return float(np.linalg.norm(g[None, :, None] * X - A) / np.linalg.norm(A))


def oracle_key_vertex_gain(DT, TD, TN, SN, held, sweeps=60):
    """Relative error over ``held`` of the best product of a per-key scale ``s_k`` and a per-vertex gain ``g_v``
    fitted to the held-out keys themselves: ``min Σ_k Σ_v ‖s_k g_v X_k(v) − A_k(v)‖²`` by alternating least
    squares (each sweep solves one factor exactly, so the error never grows) — the ceiling of every correction
    that only rescales, a key's size at every vertex included, which no one-key example can state for
    another key."""
    A, X = _held(DT, TD, TN, SN, held)
    ax, xx = np.einsum("kvi,kvi->kv", A, X), np.einsum("kvi,kvi->kv", X, X)
    s = np.ones(len(held))
    for _ in range(sweeps):
        g = (s[:, None] * ax).sum(axis=0) / np.maximum((s[:, None] ** 2 * xx).sum(axis=0), 1e-300)
        s = (g[None] * ax).sum(axis=1) / np.maximum((g[None] ** 2 * xx).sum(axis=1), 1e-300)
    return float(np.linalg.norm((s[:, None] * g[None])[..., None] * X - A) / np.linalg.norm(A))


def oracle_linear(DT, TD, TN, SN, held):
    """Relative error over ``held`` of the best per-vertex linear map ``L_v`` (3×3) fitted to the held-out keys
    themselves, ``min Σ_k ‖L_v X_k(v) − A_k(v)‖²`` per vertex (9 unknowns against 3 × the held-out keys'
    equations; a vertex no key moves keeps ``L_v = 0``, which changes nothing there) — the ceiling of every
    per-vertex map of the transferred motion, direction included."""
    A, X = _held(DT, TD, TN, SN, held)
    M = np.einsum("kvi,kvj->vij", X, X)
    B = np.einsum("kvi,kvj->vij", A, X)
    ridge = 1e-12 * np.trace(M, axis1=1, axis2=2)[:, None, None] + 1e-300
    L = np.linalg.solve(M + ridge * np.eye(3), B.transpose(0, 2, 1)).transpose(0, 2, 1)
    return float(np.linalg.norm(np.einsum("vij,kvj->kvi", L, X) - A) / np.linalg.norm(A))


def refine(T, TT, TD, TN, SN, DT, keys, combo, given=None):
    """Refine ``DT`` with the example set made with weight ``combo`` (:func:`example_set`) and given to the
    refinement with ``given`` (default: the same); (refinement, example names)."""
    from shapespace.core.authoring.examples import closing_keys, mirror_partners, refine_with_examples
    chosen, rows = example_set(keys, combo)
    _, told = example_set(keys, combo if given is None else given)
    W = np.zeros((len(rows), len(SN)))
    E = np.zeros((len(rows), T.shape[0], 3))
    for e, (row, said) in enumerate(zip(rows, told)):
        for name, w in row.items():
            W[e, SN.index(name)] = said[name]
            E[e] += w * TD[TN.index(name)]
    names = [" + ".join(row) for row in rows]
    return refine_with_examples(T, TT, DT, E, W, names=names, partners=mirror_partners(SN),
                                closers=closing_keys(SN)), chosen


def pair_metrics(src, dst, src_tag, dst_tag, kinds=None):
    """Metrics of one ordered pair (keys without the pair suffix); ``kinds``: the target's parts its rig moves
    (:func:`bench_transfer_v2.read_head_keyed`)."""
    T, TT, TD, TN = dst
    SN = src[3]
    DT = v2.transferred(src, dst, src_tag, dst_tag, kinds)[0]
    keys = authored_keys(TD, TN, SN)
    out = {}
    for combo, given, tag in ((0.0, None, ""), (COMBO_WEIGHT, None, "_combo"),
                              (APPROX_TRUE_WEIGHT, COMBO_WEIGHT, "_approx")):
        t0 = time.perf_counter()
        ref, chosen = refine(T, TT, TD, TN, SN, DT, keys, combo, given)
        seconds = time.perf_counter() - t0
        held = [n for n in keys if n not in chosen]
        plain, refined, worse, ratio = held_out_scores(DT, ref.deltas, TD, TN, SN, held)
        out[f"transfer_rel_energy_examples5{tag}"] = refined
        out[f"transfer_examples{tag}_heldout_worse_keys"] = worse
        out[f"transfer_examples{tag}_heldout_not_worse"] = bool(refined <= plain)
        if not tag:
            out["transfer_rel_energy_plain_heldout"] = plain
            out["transfer_rel_energy_oracle_gain_heldout"] = oracle_gain(DT, TD, TN, SN, held)
            out["transfer_rel_energy_oracle_key_gain_heldout"] = oracle_key_vertex_gain(DT, TD, TN, SN, held)
            out["transfer_rel_energy_oracle_linear_heldout"] = oracle_linear(DT, TD, TN, SN, held)
            out["transfer_examples_residual"] = float(ref.residual_after.max())
            out["transfer_examples_s"] = seconds
            out["transfer_examples_heldout_keys"] = len(held)
            out["transfer_examples_heldout_worst_ratio"] = ratio
    return out


def run(quick: bool = False) -> dict:
    """Every key of every ordered pair (``quick`` computes the same: the suite has no repetitions)."""
    loaded = {tag: v2.read_head_keyed(tag) for tag in v2.HEADS}
    heads = {tag: None if h is None else h[0] for tag, h in loaded.items()}
    out = {}
    for s in v2.HEADS:
        for d in v2.HEADS:
            if s == d or heads[s] is None or heads[d] is None:
                continue
            m = pair_metrics(heads[s], heads[d], s, d, loaded[d][2])
            out.update({f"{k}_{s}_{d}": v for k, v in m.items()})
            print(f"bench examples: {s} -> {d}: held-out plain {m['transfer_rel_energy_plain_heldout']:.3f} "
                  f"refined {m['transfer_rel_energy_examples5']:.3f} (worse "
                  f"{m['transfer_examples_heldout_worse_keys']}/{m['transfer_examples_heldout_keys']}), combo "
                  f"{m['transfer_rel_energy_examples5_combo']:.3f} (worse "
                  f"{m['transfer_examples_combo_heldout_worse_keys']}), approximate weights "
                  f"{m['transfer_rel_energy_examples5_approx']:.3f} (worse "
                  f"{m['transfer_examples_approx_heldout_worse_keys']})", file=sys.stderr)
    return out
