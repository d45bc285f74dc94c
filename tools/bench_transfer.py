"""Model-transfer benchmark (issue #13 §2): deformation transfer between three artist-made ARKit rigs.

For every ordered pair (source → target) among facecap (2.7k vertices), FBHead (1.5k) and ICT FaceKit
(27k): landmarks from the shapes both rigs share (``core.authoring.landmarks_from_shared_shapes``, skin part
only), registration of the source neutral onto the target neutral (similarity + thin-plate warp + non-rigid
ICP), deformation transfer of every source shape, and comparison with the target's own authored shape of the
same ARKit name (shapes empty on either rig are skipped):

- ``transfer_rel_<src>_<dst>``: mean over shapes of ‖ΔT − ΔA‖ / ‖ΔA‖ over all target vertices (1.0 = doing
  nothing); ``transfer_rel_naive_*`` the same for the baseline that copies each vertex's delta from its closest
  registered source point (rotated and scaled by the landmark similarity, so that it is not handicapped by the
  rigs' different axes and units);
- ``transfer_err_mm_*`` / ``transfer_err_mm_naive_*``: mean over shapes of the per-vertex RMS error, mm with the
  target head scaled to a 30 cm bounding-box diagonal;
- ``transfer_worst_*``: the 5 shapes with the largest relative error;
- ``transfer_s_*``: wall time of landmarks + registration + factorisation + transfer of ALL the source's shapes;
- ``registration_residual_mm_*``: RMS distance of the registered source to the target surface (mm);
- ``transfer_rel_amp_*`` (diagnostic): the relative error left if each transferred shape were given its best
  scalar amplitude (an oracle) — how much of the error is the artists' different amplitudes;
  ``transfer_rel_amp_naive_*`` the same for the naive copy; ``transfer_gap_naive_*`` (diagnostic): mean over
  shapes of ‖ΔT − Δnaive‖ / ‖ΔA‖, how far deformation transfer departs from the naive copy at all (by the
  triangle inequality, halving the naive error needs at least half the naive error here);
- ``registration_status_*``, ``registration_iterations_*``, ``registration_level_iterations_*``: the
  registration's status (OK unless a stiffness level hit its iteration cap) and its steps (per level);
- ``transfer_rel_auto_*``, ``transfer_err_mm_auto_*``, ``registration_residual_mm_auto_*`` (pairs whose source
  is facecap or FBHead): the same with landmarks proposed automatically (``propose_landmark_pairs``: the
  target's shapes are not used at all);
- ``capture_diff_mm_llf_fbhead``: the Live Link Face recording drives (copy method: weights by name, clipped
  to the slider ranges [0, 1]) both the FBHead rig with facecap's shapes transferred and FBHead's authored
  rig; per-vertex RMS difference over all frames, mm (linear blendshape evaluation, exactly what Blender's
  relative keys compute);
- symmetry keys from ``bench_symmetry.run`` (helper E's suite) when that file is present;
- the transfer v2 keys of issue #22 (``bench_transfer_v2``: whole heads with their parts, every ordered pair of
  Face Cap, FBHead, ICT FaceKit and Ready Player Me; ``transfer_s_<pair>`` there replaces the v1 time of the
  same pair and includes registration and parts);
- ``landmark_auto_err_mm_<head>`` / ``landmark_auto_unflagged_err_mm_<head>`` (``bench_landmarks``): the named
  landmarks proposed automatically against the placed ones;
- ``transfer_rel_energy_examples5_<pair>`` and the other ``bench_examples`` keys: five target keys given as
  examples, the other keys refined (``core.authoring.examples``).
"""
from __future__ import annotations

import os
import sys
import time

import numpy as np

import bench_examples
import bench_landmarks
import bench_transfer_v2
from bench_support import ASSETS

HEADS = ("facecap", "fbhead", "ict")                # the v1 suite's heads (read by bench_landmarks.read_head)
PAIRS = (("ict", "fbhead"), ("ict", "facecap"), ("facecap", "fbhead"), ("fbhead", "facecap"),
         ("facecap", "ict"), ("fbhead", "ict"))


def _scores(SN, TN, TD, deltas, empty, mm):
    """Per-shape relative and mm errors of ``deltas`` (k_s, n_t, 3) against the target's authored shapes."""
    from shapespace.core.names import canonical_name
    t_by = {canonical_name(n): j for j, n in enumerate(TN)}
    rel, err, amp, names = [], [], [], []
    for i, n in enumerate(SN):
        j = t_by.get(canonical_name(n))
        if j is None or n in empty or not np.any(TD[j]):
            continue
        dA, dT = TD[j], deltas[i]
        na = np.linalg.norm(dA)
        rel.append(np.linalg.norm(dT - dA) / na)
        err.append(np.sqrt(np.mean(np.sum((dT - dA) ** 2, axis=1))) * mm)
        g = np.sum(dT * dA) / max(np.sum(dT * dT), 1e-300)
        amp.append(np.linalg.norm(g * dT - dA) / na)
        names.append(canonical_name(TN[j]))
    return np.array(rel), np.array(err), np.array(amp), names


def _auto(src, dst):
    """The same pair with landmarks proposed automatically (the target's shapes unused)."""
    from shapespace.core import authoring
    SV, ST, SD, SN = src
    TV, TT, TD, TN = dst
    prop = authoring.propose_landmark_pairs(SV, ST, SD, SN, TV, TT)
    reg = authoring.register(SV, ST, TV, TT, prop.value)
    res = authoring.transfer_shapes(SV, ST, SD, SN, TV, TT, reg.value, naming="source")
    rel, err, _, _ = _scores(SN, TN, TD, res.value.deltas, res.value.empty, reg.value.mm_per_unit)
    return {"transfer_rel_auto": float(rel.mean()), "transfer_err_mm_auto": float(err.mean()),
            "registration_residual_mm_auto": float(reg.value.residual_mm), "transfer_landmarks_auto": len(prop.value)}


def _pair(src, dst):
    """Run one ordered pair; returns (metrics dict with the pair suffix, transferred deltas by target name)."""
    from shapespace.core import authoring
    from shapespace.core.names import canonical_name
    SV, ST, SD, SN = src
    TV, TT, TD, TN = dst
    t0 = time.perf_counter()
    s_part, _ = authoring.triangle_parts(SV.shape[0], ST)
    t_part, _ = authoring.triangle_parts(TV.shape[0], TT)
    lm = authoring.landmarks_from_shared_shapes(SV, SD, SN, TV, TD, TN, src_mask=s_part == 0, dst_mask=t_part == 0)
    reg = authoring.register(SV, ST, TV, TT, lm.value)
    corr = reg.value
    res = authoring.transfer_shapes(SV, ST, SD, SN, TV, TT, corr, naming="source")
    seconds = time.perf_counter() - t0
    out = res.value
    naive = authoring.Transfer(SV, ST, TV, TT, corr).naive(SD)
    mm = corr.mm_per_unit
    rel, err, amp, names = _scores(SN, TN, TD, out.deltas, out.empty, mm)
    reln, errn, ampn, _ = _scores(SN, TN, TD, naive, out.empty, mm)
    # ‖ΔT − Δnaive‖ / ‖ΔA‖: how far deformation transfer departs from the naive copy (the scores of the
    # "deltas" ΔT − Δnaive + ΔA against ΔA are exactly that)
    t_idx = {canonical_name(n): j for j, n in enumerate(TN)}
    auth = np.stack([TD[t_idx[canonical_name(n)]] if canonical_name(n) in t_idx else np.zeros_like(TD[0]) for n in SN])
    gap, _, _, _ = _scores(SN, TN, TD, out.deltas - naive + auth, out.empty, mm)
    t_by = {canonical_name(n): j for j, n in enumerate(TN)}
    by_name = {TN[t_by[canonical_name(n)]]: out.deltas[i] for i, n in enumerate(SN) if canonical_name(n) in t_by}
    worst = [names[k] for k in np.argsort(rel)[::-1][:5]]
    m = {"transfer_rel": float(rel.mean()), "transfer_rel_naive": float(reln.mean()),
         "transfer_err_mm": float(err.mean()), "transfer_err_mm_naive": float(errn.mean()),
         "transfer_worst": worst, "transfer_s": seconds, "registration_residual_mm": float(corr.residual_mm),
         "transfer_rel_amp": float(amp.mean()), "transfer_rel_amp_naive": float(ampn.mean()),
         "transfer_gap_naive": float(gap.mean()), "transfer_shapes_compared": int(rel.size),
         "transfer_shapes_total": len(SN), "transfer_landmarks": len(lm.value),
         "registration_status": reg.status.name, "registration_iterations": reg.iterations,
         "registration_level_iterations": list(reg.diagnostics.get("level_iterations", []))}
    return m, by_name


def _capture_diff(fbhead, transferred):
    """Live Link Face recording (copy method) on FBHead: transferred vs authored shapes, per-vertex RMS (mm)."""
    import bpy

    from shapespace.bridge import retarget
    from shapespace.core import authoring
    from shapespace.core.names import canonical_name
    V, _, D, N = fbhead
    scene = bpy.context.scene
    csv = os.path.join(ASSETS, "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")
    names, _, W, _ = retarget.read_source(csv, scene)
    col = {canonical_name(n): c for c, n in enumerate(names)}
    rows = [(k, col[canonical_name(n)]) for k, n in enumerate(N) if canonical_name(n) in col and n in transferred]
    A = np.stack([D[k] for k, _ in rows]).reshape(len(rows), -1)                 # (m, 3n)
    T = np.stack([transferred[N[k]] for k, _ in rows]).reshape(len(rows), -1)
    w = np.clip(W[:, [c for _, c in rows]], 0.0, 1.0)                           # (F, m)
    E = w @ (T - A)                                                             # (F, 3n)
    return float(np.sqrt(np.mean(np.sum(E.reshape(E.shape[0], -1, 3) ** 2, axis=2)))) * authoring.mm_per_unit(V)


def run(quick: bool = False) -> dict:
    """All metrics (``quick`` computes the same ones: the suite has no repetitions to cut)."""
    import package
    package.load()
    heads = {tag: bench_landmarks.read_head(tag) for tag in HEADS}
    out = {}
    fb_transferred = None
    for s, d in PAIRS:
        if heads[s] is None or heads[d] is None:
            continue
        m, by_name = _pair(heads[s], heads[d])
        if s != "ict":          # a 27k-vertex source registers slowly: automatic landmarks on the other four pairs
            m.update(_auto(heads[s], heads[d]))
        for k, v in m.items():
            out[f"{k}_{s}_{d}"] = v
        if (s, d) == ("facecap", "fbhead"):
            fb_transferred = by_name
        print(f"bench transfer: {s} -> {d}: rel {m['transfer_rel']:.3f} (naive {m['transfer_rel_naive']:.3f}) "
              f"{m['transfer_s']:.1f} s", file=sys.stderr)
    if fb_transferred is not None:
        from shapespace.bridge import assets
        assets.load(os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend"))
        out["capture_diff_mm_llf_fbhead"] = _capture_diff(heads["fbhead"], fb_transferred)
    try:
        import bench_symmetry
    except ImportError:
        bench_symmetry = None
    if bench_symmetry is not None:
        out.update(bench_symmetry.run(quick=quick))
    out.update(bench_transfer_v2.run(quick=quick))        # issue #22: whole heads, every ordered pair of four
    out.update(bench_landmarks.run(quick=quick))          # issue #22 §3: named landmarks, automatic vs placed
    out.update(bench_examples.run(quick=quick))           # issue #22 §5: example-guided refinement
    return out
