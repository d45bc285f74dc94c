"""Retargeting benchmark (issue #5): space-time speed vs explicit and per-frame solves, memory, bounds,
velocity error on real captures, key reduction."""
from __future__ import annotations

import functools
import os
import time
import tracemalloc

import numpy as np

from bench_support import ASSETS, shared_data
from synthetic_rigs import arkit_columns, redundant_head_rig


def _problem(F, n, m3, seed=0, dtype=np.float64):
    rng = np.random.default_rng(seed)
    B = rng.normal(size=(m3, n)) * 0.1
    b0 = rng.normal(size=m3)
    W = np.cumsum(rng.normal(size=(F, n)) * 0.05, axis=0)
    S = np.empty((F, m3), dtype=dtype)
    for start in range(0, F, 1024):
        rows = slice(start, min(start + 1024, F))
        S[rows] = b0 + W[rows] @ B.T + rng.normal(size=(rows.stop - rows.start, m3)) * 0.01
    return B, b0, S, W


def _explicit(B, b0, S, sigma, lam, first, last):
    import scipy.sparse as sp
    from scipy.sparse.linalg import spsolve
    F, n = S.shape[0], B.shape[1]
    D = sp.diags([-np.ones(F - 1), np.ones(F - 1)], [0, 1], shape=(F - 1, F))
    DtD = (D.T @ D).tocsc()
    G = B.T @ B
    inner = slice(1, F - 1)
    K = sp.kron(DtD[inner][:, inner], sp.csc_matrix(G)) + lam * sp.kron(sp.eye(F - 2), sp.diags(1 / sigma ** 2))
    rhs = (DtD @ ((S - b0) @ B))[1:-1]
    rhs[0] += first @ G
    rhs[-1] += last @ G
    return spsolve(K.tocsc(), rhs.ravel()).reshape(F - 2, n)


def speed(quick):
    from shapespace.core.retarget import spacetime
    reps = 2 if quick else 5
    out = {}
    B, b0, S, W = _problem(500, 52, 3000)
    sigma, lam = np.full(52, 0.3), 1e-3
    best = lambda f: min(_timed(f) for _ in range(reps))  # noqa: E731
    res = spacetime(B, b0, S, sigma, lam)
    out["spacetime_s_500x52"] = best(lambda: spacetime(B, b0, S, sigma, lam))
    ref = _explicit(B, b0, S, sigma, lam, res.weights[0], res.weights[-1])
    out["explicit_s_500x52"] = best(lambda: _explicit(B, b0, S, sigma, lam, res.weights[0], res.weights[-1]))
    out["spacetime_vs_explicit_max_abs_diff"] = float(np.abs(ref - res.weights[1:-1]).max())
    G = B.T @ B
    out["perframe_s_500x52"] = best(lambda: np.linalg.solve(G, ((S - b0) @ B).T).T)   # per-frame least squares
    out["explicit_over_spacetime"] = out["explicit_s_500x52"] / out["spacetime_s_500x52"]
    out["spacetime_over_perframe"] = out["spacetime_s_500x52"] / out["perframe_s_500x52"]
    lo, hi = np.full(52, -0.5), np.full(52, 0.5)
    bounded = spacetime(B, b0, S, sigma, lam, lo=lo, hi=hi)
    out["bounded_s_500x52"] = best(lambda: spacetime(B, b0, S, sigma, lam, lo=lo, hi=hi))
    out["bounded_newton_iterations"] = bounded.iterations
    out["bounded_inner_solves"] = bounded.diagnostics.get("solves", 0)
    out["bounded_over_unbounded"] = out["bounded_s_500x52"] / out["spacetime_s_500x52"]
    # a long shot: 10,000 frames × 150 targets × 15k coordinates (source kept in float32)
    B, b0, S, W = _problem(10000, 150, 15000, seed=1, dtype=np.float32)
    tracemalloc.start()
    t = time.perf_counter()
    spacetime(B, b0, S, np.full(150, 0.3), lam)
    out["spacetime_s_10000x150"] = time.perf_counter() - t
    out["spacetime_peak_gb_10000x150"] = tracemalloc.get_traced_memory()[1] / 1e9
    tracemalloc.stop()
    out["source_gb_10000x150"] = S.nbytes / 1e9
    return out


def _timed(fn):
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def _plot_channel(curves, path):
    """Fig. 3.9 style: one channel (jawOpen, slider limited to 0.4) — the capture, copying (clipped),
    per-frame fitting and space-time cloning."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(9, 3.6), dpi=110)
    style = {"capture": ("capture (target cannot follow above 0.4)", "0.6", "--"),
             "copy": ("copy weights (clipped)", "tab:red", ":"), "perframe": ("per-frame fit", "tab:orange", "-"),
             "spacetime": ("space-time (ch. 5)", "tab:blue", "-")}
    for key in ("capture", "copy", "perframe", "spacetime"):
        label, color, ls = style[key]
        ax.plot(*curves[key], ls, color=color, label=label, lw=1.6 if key == "spacetime" else 1.1,
                zorder=5 if key in ("capture", "copy") else 3)
    ax.axhline(0.4, color="k", lw=0.6)
    ax.set_xlabel("frame")
    ax.set_ylabel("jawOpen")
    ax.set_title("facecap capture → facecap with jawOpen limited to 0.4")
    ax.legend(loc="upper left", fontsize=8, ncol=2)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def _facecap_reduced():
    """The Face Cap head with six sliders limited to 0.4 (the target cannot follow), its capture detached."""
    import bpy

    from shapespace.bridge import actions, assets
    assets.load(os.path.join(ASSETS, "facecap", "facecap_decoded.glb"))
    ob = bpy.data.objects["Mesh_2"]
    key = ob.data.shape_keys
    capture = actions.active_action(key)
    key.animation_data.action = None
    for name in ("jawOpen", "mouthSmile_L", "mouthSmile_R", "eyeBlink_L", "eyeBlink_R", "browInnerUp"):
        key.key_blocks[name].slider_max = 0.4
    return ob, key, capture


def quality(plot_path=None):
    """Real captures: facecap's capture onto facecap with reduced slider ranges; LLF onto FBHead."""
    import bpy

    from shapespace.bridge import actions, assets, retarget
    out = {}
    ob, key, capture = _facecap_reduced()
    curves = {}
    for method in ("copy", "perframe", "spacetime"):
        rep = retarget.retarget(ob, capture, method)
        if method != "copy":
            out[f"velocity_err_{method}_facecap_reduced"] = rep["velocity_error_rms"]
            out[f"position_err_{method}_facecap_reduced"] = rep["position_error_rms"]
            out["clipping_frames_facecap_reduced"] = rep["clipping_frames"]
        fc = actions.shape_key_curves(ob, bpy.data.actions[rep["action"]])["jawOpen"]
        curves[method] = actions.read_curve(fc)[:2]
    curves["capture"] = (curves["copy"][0], actions.sample_curve(
        actions.shape_key_curves(ob, capture)["jawOpen"], curves["copy"][0]))
    if plot_path:
        _plot_channel(curves, plot_path)
    assets.load(os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend"))
    ob = bpy.data.objects["FBHead"]
    csv = os.path.join(ASSETS, "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")
    for method in ("perframe", "spacetime"):
        rep = retarget.retarget(ob, csv, method)
        out[f"velocity_err_{method}_llf_fbhead"] = rep["velocity_error_rms"]
        out[f"position_err_{method}_llf_fbhead"] = rep["position_error_rms"]
    return out


def _max_errors(curves_by_name, names, frames, dense):
    """Max |curve − dense| per channel, evaluated by Blender (``FCurve.evaluate``)."""
    return np.array([max(abs(curves_by_name[nm].evaluate(float(f)) - dense[i, j]) for i, f in enumerate(frames))
                     for j, nm in enumerate(names)])


def key_reduction(quick):
    """Keys kept at max error ≤ 0.01: our DP on the dense space-time curves vs Blender's Decimate
    (Graph Editor, 'Allowed Change'), each curve's Decimate margin bisected to the largest one whose
    real max error (Blender's own evaluation) stays ≤ 0.01 — the most generous setting for Decimate."""
    import bpy

    from shapespace.bridge import actions, retarget
    tol = 0.01
    ob, key, capture = _facecap_reduced()
    rep = retarget.retarget(ob, capture, "spacetime", action_name="dense")
    dense_action = bpy.data.actions[rep["action"]]
    curves = actions.shape_key_curves(ob, dense_action)
    names = sorted(n for n, fc in curves.items() if np.ptp(actions.read_curve(fc)[1]) > 0)
    frames = actions.read_curve(curves[names[0]])[0]
    if quick:
        names = names[::3]
    dense = np.column_stack([actions.read_curve(curves[n])[1] for n in names])
    out = {}
    for shape in ("BEZIER", "LINEAR"):                 # ours: exact DP, smooth Bézier or linear keys
        ours = dense_action.copy()
        actions.assign_action(key, ours)
        frac = retarget.reduce_action_keys(ob, names, frames, dense, tol, shape)
        err = float(_max_errors(actions.shape_key_curves(ob, ours), names, frames, dense).max())
        suffix = "" if shape == "BEZIER" else "_linear"
        out[f"keys_kept_frac_ours{suffix}"], out[f"keys_max_err_ours{suffix}"] = frac, err
    dec_keys, dec_err, dec_keys_at_tol = 0, 0.0, 0
    for j, nm in enumerate(names):
        lo_m, hi_m, best = 0.0, 0.5, None
        for _ in range(8 if quick else 14):
            mid = 0.5 * (lo_m + hi_m) if best is not None or lo_m > 0 else tol
            trial = dense_action.copy()
            actions.assign_action(key, trial)
            fc = actions.shape_key_curves(ob, trial)[nm]
            actions.blender_decimate(key, trial, [fc], mid)
            err = float(_max_errors({nm: fc}, [nm], frames, dense[:, [j]]).max())
            n_keys = len(fc.keyframe_points)
            bpy.data.actions.remove(trial)
            if mid == tol and best is None:
                dec_keys_at_tol += n_keys      # Decimate run with margin = tolerance, as an artist would
            if err <= tol:
                best = (n_keys, err) if best is None or n_keys < best[0] else best
                lo_m = mid
            else:
                hi_m = mid
        best = best or (frames.size, 0.0)
        dec_keys += best[0]
        dec_err = max(dec_err, best[1])
    total = frames.size * len(names)
    return {**out, "keys_kept_frac_decimate": dec_keys / total, "keys_max_err_decimate": dec_err,
            "keys_kept_frac_decimate_margin_eq_tol": dec_keys_at_tol / total,
            "keys_reduction_curves": len(names), "keys_reduction_tol": tol}


def _one_exact_solve_s(args, kwargs, res, reps=3) -> float:
    """Seconds of ONE exact solve with the final active set held (a block-tridiagonal Cholesky factor and
    its two sweeps, O(f n³)): the floor of any exact active-set method on this problem, to set beside the
    unbounded solve (whose per-mode tridiagonal sweeps are O(f n²) in a few compiled calls)."""
    from shapespace.core.blas_threads import single_threaded
    from shapespace.core.retarget import spacetime_solver as ss
    B, b0, S, sig, lam = args[:5]
    lo, hi = np.broadcast_to(kwargs["lo"], sig.shape), np.broadcast_to(kwargs["hi"], sig.shape)
    system = ss.SpacetimeSystem(np.asarray(B, dtype=np.float64), np.asarray(sig), lam, S.shape[0],
                                kwargs.get("relative", False), kwargs.get("beta", 0.0))
    W = res.weights[1:-1]
    held = (W <= lo + 1e-12) | (W >= hi - 1e-12)
    r = np.random.default_rng(0).normal(size=held.shape)
    with single_threaded():
        return min(_timed(lambda: ss.BlockCholesky(system, held).solve(r)) for _ in range(reps))


def _one_compiled_factorisation_s(args, kwargs, reps=3) -> float:
    """Seconds of ONE compiled factorisation of the coupled space-time operator: LAPACK ``dpbtrf`` on its band
    (bandwidth 2n − 1, nothing held — the cheapest coupled system there is), with no Python per frame.  Beside
    the unbounded solve it is the flop floor of any exact bounded solve, whatever language it is written in."""
    from scipy.linalg import lapack

    from shapespace.core.blas_threads import single_threaded
    from shapespace.core.retarget import spacetime_solver as ss
    B, _, S, sig, lam = args[:5]
    system = ss.SpacetimeSystem(np.asarray(B, dtype=np.float64), np.asarray(sig), lam, S.shape[0],
                                kwargs.get("relative", False), kwargs.get("beta", 0.0))
    band = system.banded()

    def factor():
        _, info = lapack.dpbtrf(band.copy(), lower=0)
        assert info == 0, f"dpbtrf info {info}"
    with single_threaded():
        return min(_timed(factor) for _ in range(reps))


def landmark_cases():
    """The facecap capture as a mesh performance onto other topologies through landmarks placed from the
    shapes the rigs share (peak vertices), then rigid + thin-plate warp and closest points: FBHead
    (1.5k vertices) and ICT FaceKit (27k, skipped without ../shared/data).  Also times the bounded vs
    unbounded space-time solve on the real FBHead problem (slider ranges [0, 1], dense noisy correspondence)."""
    import bpy

    from shapespace.bridge import assets, retarget
    from shapespace.core.retarget import performance
    out = {}
    assets.load(os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend"))
    assets.load(os.path.join(ASSETS, "facecap", "facecap_decoded.glb"), replace=False)
    ict = shared_data(os.path.join("ict_facekit", "ict_facekit_expressions.glb"), "the ICT FaceKit landmark case")
    if ict:
        assets.load(ict, replace=False)
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 268
    src = bpy.data.objects["Mesh_2"]
    timed = {}
    original = performance.spacetime

    def timing_spacetime(*args, **kwargs):       # the retarget's own solve, best of 3 with and without bounds
        free = {k: v for k, v in kwargs.items() if k not in ("lo", "hi")}
        timed["bounded"] = min(_timed(lambda: original(*args, **kwargs)) for _ in range(3))
        timed["unbounded"] = min(_timed(lambda: original(*args, **free)) for _ in range(3))
        res = original(*args, **kwargs)
        timed["iterations"] = res.iterations
        timed["one_exact"] = _one_exact_solve_s(args, kwargs, res)
        timed["one_compiled"] = _one_compiled_factorisation_s(args, kwargs)
        return res

    cases = (("facecap_fbhead_landmarks", "FBHead"), ("facecap_ict_landmarks", "ICTFace"))
    for case, target in cases if ict else cases[:1]:
        ob = bpy.data.objects[target]
        out[f"landmarks_{case}"] = len(retarget.landmarks_from_shapes(src, ob))
        for method in ("perframe", "spacetime"):
            performance.spacetime = timing_spacetime if case == "facecap_fbhead_landmarks" else original
            try:
                rep = retarget.retarget_dense(ob, src, method)
            finally:
                performance.spacetime = original
            out[f"velocity_err_{method}_{case}"] = rep["velocity_error_rms"]
            out[f"position_err_{method}_{case}"] = rep["position_error_rms"]
            out[f"clipping_frames_{case}"] = rep["clipping_frames"]
    out["bounded_s_real_fbhead"] = timed["bounded"]
    out["unbounded_s_real_fbhead"] = timed["unbounded"]
    out["bounded_over_unbounded_real_fbhead"] = timed["bounded"] / timed["unbounded"]
    out["bounded_iterations_real_fbhead"] = timed["iterations"]
    out["one_exact_solve_over_unbounded_real_fbhead"] = timed["one_exact"] / timed["unbounded"]
    out["one_compiled_factorisation_over_unbounded_real_fbhead"] = timed["one_compiled"] / timed["unbounded"]
    return out


# ------------------------------------------------------------------ production scale (issue #11)
def _tiled_llf(count: int):
    """FBHead and the Live Link Face take tiled to ``count`` frames (names, frames, weights), via the bridge."""
    import bpy

    from shapespace.bridge import assets, retarget
    assets.load(os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend"))
    csv = os.path.join(ASSETS, "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")
    names, frames, src, issues = retarget.read_source(csv, bpy.context.scene)
    src = np.tile(src, (-(-count // src.shape[0]), 1))[:count]
    return bpy.data.objects["FBHead"], names, frames[0] + np.arange(src.shape[0], dtype=np.float64), src, issues


def _position_mm(D, model):
    """Per-vertex position error: RMS over vertices and frames of ‖ΔW Bᵀ‖ (mm, head scaled to a 30 cm
    bounding-box diagonal); ``D`` (f, n) weight errors."""
    from shapespace.core.blendshape import bounding_box_diagonal
    mm = 300.0 / bounding_box_diagonal(model.neutral)
    sq = 0.0
    for start in range(0, D.shape[0], 256):
        E = (D[start:start + 256] @ model.delta_matrix.T).reshape(-1, model.n_vertices, 3)
        sq += float(np.sum(E * E))
    return float(np.sqrt(sq / (D.shape[0] * model.n_vertices))) * mm


def _tiled_csv(folder: str, frames: int, fps: float) -> str:
    """The shipped Live Link Face CSV looped to cover ``frames`` scene frames at ``fps`` (continuous 60 fps
    timecode, rows taken cyclically: 1,640 frames at 30 fps is the take tiled 10×)."""
    src = os.path.join(ASSETS, "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")
    with open(src, encoding="utf-8") as fh:
        lines = fh.read().splitlines()
    head, rows = lines[0], [ln.split(",", 1)[1] for ln in lines[1:] if ln.strip()]
    count = int(np.ceil((frames - 1) * 60.0 / fps)) + 1
    path = os.path.join(folder, f"take_{frames}_{fps:g}fps.csv")
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(head + "\n")
        for k in range(count):
            t = k / 60.0
            h, rem = divmod(t, 3600.0)
            m, rem = divmod(rem, 60.0)
            s = int(rem)
            fh.write(f"{int(h):02d}:{int(m):02d}:{s:02d}:{(rem - s) * 60:06.3f},{rows[k % len(rows)]}\n")
    return path


#: Runs the batch command as a child and reports its wall time, exit code, peak RSS and JSON (``--timeout``).
_CHILD = """
import json, resource, subprocess, sys, time
limit = float(sys.argv[1])
t = time.perf_counter()
try:
    p = subprocess.run(sys.argv[2:], capture_output=True, text=True, timeout=limit)
    rc, out, err, timed_out = p.returncode, p.stdout, p.stderr, False
except subprocess.TimeoutExpired as exc:
    rc, out, err, timed_out = None, "", (exc.stderr or b"").decode(errors="replace"), True
print(json.dumps({"s": time.perf_counter() - t, "rc": rc, "timed_out": timed_out, "out": out, "err": err[-3000:],
                  "peak_gb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024 / 1e9}))
"""


def _batch(target: str, csv: str, method: str, obj: str = None, timeout: float = 1800.0) -> dict:
    """``tools/run_cli.py TARGET -- retarget --source CSV --method M --key-tolerance 0.01 --dry-run``, the whole
    command (Blender start-up, file load, read, solve, key reduction, writing the action) in a child process:
    ``{s, rc, timed_out, peak_gb, result (the source's JSON report or None), source_s (its progress line)}``."""
    import json
    import re
    import subprocess
    import sys
    cmd = [sys.executable, os.path.join(os.path.dirname(os.path.abspath(__file__)), "run_cli.py"), target, "--",
           "retarget", "--source", csv, "--method", method, "--key-tolerance", "0.01", "--dry-run"]
    if obj:
        cmd += ["--object", obj]
    proc = subprocess.run([sys.executable, "-c", _CHILD, str(timeout), *cmd], capture_output=True, text=True)
    run = json.loads(proc.stdout.strip().splitlines()[-1])
    run["result"] = None
    if run["rc"] == 0:
        run["result"] = json.loads(run["out"][run["out"].index("{"):])["results"][0]
    line = re.search(r": (\d+) frames in ([\d.]+) s \(", run["err"])
    run["source_s"] = float(line.group(2)) if line else None
    if run["rc"] != 0:
        print(f"bench: batch {method} on {os.path.basename(target)} failed: {run['err'][-400:]}", file=sys.stderr)
    return run


def longtake(quick):
    """Production scale (#11).  The batch command, timed whole in a child process (start-up and file load
    included; ``…_source_s`` is its own per-source time), on the shipped Live Link Face take looped to 1,640
    frames, each method onto FBHead (30 fps) and ICT FaceKit (27k vertices, 24 fps), key reduction at 0.01;
    then 36,000 frames (10 minutes at 60 fps: 20 minutes of capture at FBHead's 30 fps, 25 at ICT's 24), every
    method onto FBHead and onto ICT FaceKit (``--quick``: spacetime onto FBHead only), wall time and peak RSS
    of the command.  In-process on the same 1,640 frames with nothing to clip (sliders
    widened): the end-of-take drift of space-time and the position errors — ``position_err_<m>_longtake_noclip``
    per vertex (RMS over vertices and frames, mm with the head scaled to a 30 cm bounding-box diagonal) and
    ``position_err_total_<m>_longtake_noclip`` today's report figure (RMS over frames of the whole-mesh
    distance ‖ΔW Bᵀ‖, over the head's size: it grows with the vertex count).  Key reduction alone: the 51
    mapped curves of the take, all at once (as the batch command reduces them).  Plus the redundant rig."""
    import tempfile

    from shapespace.bridge import retarget, shapekeys
    from shapespace.core.blendshape import bounding_box_diagonal
    from shapespace.core.keyreduce import hermite, reduce_keys_bezier_curves
    from shapespace.core.retarget import copy_weights, performance, split_mapping
    out = {}
    folder = tempfile.mkdtemp(prefix="shapespace_longtake_")
    fbhead = os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend")
    ict = shared_data(os.path.join("ict_facekit", "ict_facekit_expressions.glb"), "the ICT FaceKit long take")
    targets = [("fbhead", fbhead, None, 30.0)] + ([("ict", ict, "ICTFace", 24.0)] if ict else [])
    for label, path, obj, fps in targets:
        csv = _tiled_csv(folder, 1640, fps)
        for method in ("copy", "perframe", "spacetime"):
            run = _batch(path, csv, method, obj, timeout=600.0)
            key = f"longtake_s_{method}_{label}_1640"
            out[key] = run["s"] if run["rc"] == 0 else None
            out[f"{key}_source_s"] = run["source_s"]
            out[f"longtake_peak_gb_{method}_{label}_1640"] = run["peak_gb"]
            if run["result"]:
                out[f"longtake_frames_{label}"] = run["result"]["frames"]
                out[f"longtake_keys_kept_frac_{method}_{label}_1640"] = run["result"].get("keys_kept_frac")
                if method == "spacetime":
                    out[f"longtake_converged_spacetime_{label}_1640"] = run["result"].get("converged")
    # 36,000 frames: every method onto FBHead (30 fps) and, in the full run, onto ICT FaceKit (its own 24 fps)
    for label, path, obj, fps in targets if not quick else targets[:1]:
        csv = _tiled_csv(folder, 36000, fps)
        for method in ("spacetime",) if quick else ("copy", "perframe", "spacetime"):
            run = _batch(path, csv, method, obj, timeout=240.0 if quick else 1800.0)  # a timeout is recorded
            out[f"longtake_s_{method}_{label}_36000"] = run["s"] if run["rc"] == 0 else None
            out[f"longtake_s_{method}_{label}_36000_source_s"] = run["source_s"]
            out[f"longtake_peak_gb_{method}_{label}_36000" if (method, label) != ("spacetime", "fbhead") else
                "longtake_peak_gb_fbhead_36000"] = run["peak_gb"]
            out[f"longtake_36000_{method}{'' if label == 'fbhead' else '_' + label}_timed_out"] = run["timed_out"]
            if run["result"]:
                out[f"longtake_frames_{label}_36000"] = run["result"]["frames"]
                if method == "spacetime":
                    out[f"longtake_converged_spacetime_{label}_36000"] = run["result"].get("converged")
    # in-process: no clipping, drift and position errors; key reduction alone
    ob, names, frames, src, issues = _tiled_llf(1640)
    model = shapekeys.read_blendshape_model(ob)
    model.slider_min[:], model.slider_max[:] = -10.0, 10.0                 # nothing clips
    mapping, _ = retarget.resolve_mapping(ob, names, model.names)
    pairs, gain, offset = split_mapping(mapping, model.n_targets)
    raw = copy_weights(src, pairs, model.n_targets, gain, offset)
    diag = bounding_box_diagonal(model.neutral)
    for method in ("perframe", "spacetime"):
        fit = performance.retarget_weights(model, raw, method)
        W = fit.weights
        out[f"position_err_{method}_longtake_noclip"] = _position_mm(W - raw, model)
        out[f"position_err_total_{method}_longtake_noclip"] = float(fit.position_error_rms)
        if method == "spacetime":
            tail = (W - raw)[-max(1, frames.size // 10):]
            E = (tail @ model.delta_matrix.T).reshape(tail.shape[0], model.n_vertices, 3)
            out["drift_end_rel_spacetime_noclip"] = float(np.linalg.norm(E, axis=2).max() / diag)
    dense = np.clip(raw[:, :51], 0, 1)
    tol = 0.01
    start = time.perf_counter()
    keys = reduce_keys_bezier_curves(frames, dense, tol)
    out["keyreduce_s_1640"] = time.perf_counter() - start
    out["keyreduce_keys_kept_frac_1640"] = sum(k[0].size for k in keys) / dense.size
    out["keyreduce_max_err_1640"] = max(float(np.abs(hermite(frames[i], kv, km, frames) - dense[:, j]).max())
                                        for j, (i, kv, km) in enumerate(keys))
    out["keyreduce_frames"], out["keyreduce_curves"], out["keyreduce_tol"] = int(frames.size), int(dense.shape[1]), tol
    out.update(_redundant_rig(quick))
    return out


def _spacetime_natural_residual(B, b0, S, sig, lam_abs, W, lo, hi, beta=0.0):
    """The KKT test of the anchored bounded space-time problem, rebuilt from its definition (not from the solver):
    natural residual ‖y − clip(y − ∇f)‖∞ in the whitened weights y = W/σ, over max(1, ‖∇f(0)‖∞), for
    ``f = ½‖D(W Bᵀ − S)‖² + ½β‖W Bᵀ − S‖² + ½λ‖(W − W⁰)/σ‖²`` (W⁰ the per-frame ridge fit), interior frames,
    ends fixed."""
    W0 = np.linalg.solve(B.T @ B + lam_abs * np.diag(1.0 / sig ** 2), B.T @ (S - b0).T).T

    def grad(Wi):
        Wf = np.vstack([W[0], Wi, W[-1]])
        E = Wf @ B.T - (S - b0)
        second = 2 * E[1:-1] - E[:-2] - E[2:] + beta * E[1:-1]
        return sig * (second @ B + lam_abs * (Wi - W0[1:-1]) / sig ** 2)
    y = W[1:-1] / sig
    nat = np.abs(y - np.clip(y - grad(W[1:-1]), lo / sig, hi / sig)).max()
    return float(nat / max(1.0, float(np.abs(grad(np.zeros_like(W[1:-1]))).max())))


def _redundant_head():
    """FBHead grown to a 124-key avatar face (``synthetic_rigs.redundant_head_rig``: its ARKit keys, exact, scaled
    and near duplicates, visemes, empty keys; rank ≈ 90) and the shipped Live Link Face take at 24 fps (131
    frames), its 52 ARKit channels copied onto the ARKit keys: ``(model, rig, ideal weights (131, 124))``."""
    import bpy

    from shapespace.bridge import assets, retarget, shapekeys
    from shapespace.core.blendshape import BlendshapeModel
    assets.load(os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend"))
    scene = bpy.context.scene
    scene.render.fps, scene.render.fps_base = 24, 1.0
    base = shapekeys.read_blendshape_model(bpy.data.objects["FBHead"])
    csv = os.path.join(ASSETS, "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")
    channels, frames, src, issues = retarget.read_source(csv, scene)
    rig = redundant_head_rig(arkit_columns(base.delta_matrix, base.names, channels), base.neutral, channels)
    model = BlendshapeModel(base.neutral, rig["B"], rig["names"])          # sliders [0, 1]
    ideal = np.zeros((src.shape[0], model.n_targets))
    ideal[:, :len(channels)] = src
    return model, rig, ideal


def _redundant_rig(quick):
    """The 124-key redundant face built from FBHead (:func:`_redundant_head`, rank ~90 of 124) and the 131-frame
    take: ``perframe`` and bounded ``spacetime`` as the retarget command fits them
    (``performance.retarget_weights``), each timed whole and checked against its KKT conditions rebuilt here
    (``redundant_rig_converged_*``: per-frame natural residual ≤ 1e-7 of the frame's gradient scale, the level
    the per-frame fit accepts; space-time ≤ the solver's 1e-8, and the solver says so).  The tie-break among
    equal-geometry answers is the ridge's minimum norm (per-frame: exact duplicates share equally) / the anchor
    to the σ-weighted per-frame ridge fit (space-time: duplicates share in proportion to σ²)."""
    from shapespace.core.blendshape import normalised_unit
    from shapespace.core.retarget import performance, perframe
    model, rig, ideal = _redundant_head()
    live = np.abs(model.delta_matrix).max(axis=0) > 0
    general, real_bvls = [], perframe._bvls

    def counting_bvls(*args):                              # a general solver on a frame: counted, not changed
        general.append(1)
        return real_bvls(*args)
    perframe._bvls = counting_bvls
    try:
        t = time.perf_counter()
        W = performance.retarget_weights(model, ideal, "perframe").weights
        out = {"redundant_rig_s_perframe_131": time.perf_counter() - t}
    finally:
        perframe._bvls = real_bvls
    out["redundant_rig_perframe_general_solves"] = len(general)
    unit = normalised_unit(model)
    B = model.delta_matrix[:, live] / unit
    S = ideal @ model.delta_matrix.T / unit
    G = B.T @ B
    a = 1e-6 * np.trace(G) / G.shape[0]
    Wl = W[:, live]
    grad = 2 * (Wl @ G - S @ B) + 2 * a * Wl
    nat = np.abs(Wl - np.clip(Wl - grad, 0.0, 1.0)).max(axis=1) / np.maximum(1.0, np.abs(2 * S @ B).max(axis=1))
    out["redundant_rig_natural_residual_perframe"] = float(nat.max())
    out["redundant_rig_converged_perframe"] = bool(nat.max() <= 1e-7)
    out["redundant_rig_perframe_bound_violation"] = float(max(0.0, -W.min(), W.max() - 1.0))
    out["redundant_rig_rank"] = int(rig["rank"])
    out["redundant_rig_rank_rtol"] = float(rig["rank_rtol"])
    out["redundant_rig_keys"] = int(model.n_targets)
    out["redundant_rig_frames"] = int(ideal.shape[0])
    calls, real_spacetime = [], performance.spacetime

    def recording(*args, **kwargs):                        # the problem the retarget poses, recorded
        calls.append((args, kwargs))
        return real_spacetime(*args, **kwargs)
    performance.spacetime = recording
    try:
        t = time.perf_counter()
        fit = performance.retarget_weights(model, ideal, "spacetime")
        out["redundant_rig_s_spacetime_131"] = time.perf_counter() - t
    finally:
        performance.spacetime = real_spacetime
    (args, kwargs), res = calls[0], fit.solver
    Bs, b0, Ss, sig = (np.asarray(x, dtype=np.float64) for x in args[:4])
    lam = float(args[4]) if len(args) > 4 else float(kwargs.get("lam", 1e-3))
    if kwargs.get("relative"):
        lam *= float(np.linalg.eigvalsh(sig[:, None] * (Bs.T @ Bs) * sig[None, :]).clip(0).mean())
    nat = _spacetime_natural_residual(Bs, b0, Ss, sig, lam, fit.weights[:, live], kwargs["lo"], kwargs["hi"],
                                      float(kwargs.get("beta", 0.0)))
    out["redundant_rig_natural_residual_spacetime"] = nat
    out["redundant_rig_converged_spacetime"] = bool(res.converged and nat <= 1e-8)
    out["redundant_rig_spacetime_iterations"] = res.iterations
    out["redundant_rig_spacetime_solves"] = res.diagnostics.get("solves")
    out.update(_bounded_longtake(quick))
    return out


def _bounded_longtake(quick):
    """Bounded over unbounded space-time on the 1,640-frame take onto FBHead (sliders [0, 1]): the retarget's
    own solve (``performance.retarget_weights``), timed with and without the bounds, best of 2 (1 in quick)."""
    from shapespace.bridge import retarget, shapekeys
    from shapespace.core.retarget import copy_weights, performance, split_mapping
    ob, names, frames, src, issues = _tiled_llf(1640)
    model = shapekeys.read_blendshape_model(ob)
    mapping, _ = retarget.resolve_mapping(ob, names, model.names)
    pairs, gain, offset = split_mapping(mapping, model.n_targets)
    raw = copy_weights(src, pairs, model.n_targets, gain, offset)
    timed, original = {}, performance.spacetime
    reps = 1 if quick else 2

    def timing_spacetime(*args, **kwargs):
        free = {k: v for k, v in kwargs.items() if k not in ("lo", "hi")}
        timed["bounded"] = min(_timed(lambda: original(*args, **kwargs)) for _ in range(reps))
        timed["unbounded"] = min(_timed(lambda: original(*args, **free)) for _ in range(reps))
        res = original(*args, **kwargs)
        timed["res"] = res
        timed["one_exact"] = _one_exact_solve_s(args, kwargs, res, reps)
        timed["one_compiled"] = _one_compiled_factorisation_s(args, kwargs, reps)
        return res
    performance.spacetime = timing_spacetime
    try:
        performance.retarget_weights(model, raw, "spacetime")
    finally:
        performance.spacetime = original
    res = timed["res"]
    return {"bounded_s_longtake": timed["bounded"], "unbounded_s_longtake": timed["unbounded"],
            "bounded_over_unbounded_longtake": timed["bounded"] / timed["unbounded"],
            "one_exact_solve_over_unbounded_longtake": timed["one_exact"] / timed["unbounded"],
            "one_compiled_factorisation_over_unbounded_longtake": timed["one_compiled"] / timed["unbounded"],
            "bounded_solves_longtake": res.diagnostics.get("solves"),
            "bounded_converged_longtake": bool(res.converged)}


def cancel_latency(quick):
    """Cancel (Esc) latency of a long retarget: the worker stops at its next progress call, so the longest
    gap between progress calls is the worst case.  The retarget operator's own worker work
    (``bridge.retarget.compute_retarget``) on the 1,640-frame take onto ICT FaceKit (27k vertices) with
    space-time, and the facecap mesh performance onto ICT through landmarks (dense, 268 frames): the
    longest gap (``cancel_latency_s_<case>``), and a real cancel half-way through a ``BackgroundJob``
    (``cancel_measured_s_<case>``: from ``cancel()`` to the worker's end; nothing is written either way)."""
    import tempfile

    import bpy

    from shapespace.bridge import assets, retarget
    from shapespace.core.jobs import BackgroundJob
    ict = shared_data(os.path.join("ict_facekit", "ict_facekit_expressions.glb"), "the cancel latency case")
    if not ict:
        return {}
    out = {}
    folder = tempfile.mkdtemp(prefix="shapespace_cancel_")
    assets.load(ict)
    assets.load(os.path.join(ASSETS, "facecap", "facecap_decoded.glb"), replace=False)
    scene, ob = bpy.context.scene, bpy.data.objects["ICTFace"]
    csv = _tiled_csv(folder, 1640, 24.0)
    plans = {"llf_ict_1640": lambda: retarget.read_retarget(ob, csv, method="spacetime", scene=scene)}
    if not quick:
        def dense_plan():
            scene.frame_start, scene.frame_end = 1, 268
            retarget.landmarks_from_shapes(bpy.data.objects["Mesh_2"], ob)
            return retarget.read_retarget_dense(ob, bpy.data.objects["Mesh_2"], method="spacetime", scene=scene)
        plans["facecap_ict_landmarks"] = dense_plan
    for case, make in plans.items():
        plan = make()
        stamps = [time.perf_counter()]
        retarget.compute_retarget(plan, lambda f, stamps=stamps: stamps.append(time.perf_counter()))
        stamps.append(time.perf_counter())
        whole = stamps[-1] - stamps[0]
        out[f"cancel_latency_s_{case}"] = float(np.diff(stamps).max())
        out[f"cancel_work_s_{case}"] = whole
        job = BackgroundJob(functools.partial(retarget.compute_retarget, plan)).start()
        time.sleep(0.5 * whole)
        asked = time.perf_counter()
        job.cancel()
        while not job.done:
            time.sleep(0.001)
        out[f"cancel_measured_s_{case}"] = time.perf_counter() - asked
    return out


def _head_eye_rig():
    """An armature beside FBHead: neck → head → eyes, tilted rest orientations, one rotation mode each."""
    import bpy
    data = bpy.data.armatures.new("BenchRig")
    arm = bpy.data.objects.new("BenchRig", data)
    bpy.context.scene.collection.objects.link(arm)
    bpy.context.view_layer.objects.active = arm
    bpy.ops.object.mode_set(mode="EDIT")
    for name, head, tail, roll, parent in (("neck", (0, 0, 1.4), (0, 0.02, 1.55), 0.1, None),
                                           ("head", (0, 0.02, 1.55), (0, -0.01, 1.8), -0.2, "neck"),
                                           ("eye.L", (0.03, -0.08, 1.65), (0.03, -0.1, 1.65), 0.3, "head"),
                                           ("eye.R", (-0.03, -0.08, 1.65), (-0.04, -0.1, 1.66), 0.0, "head")):
        eb = data.edit_bones.new(name)
        eb.head, eb.tail, eb.roll = head, tail, roll
        if parent:
            eb.parent = data.edit_bones[parent]
    bpy.ops.object.mode_set(mode="OBJECT")
    for name, mode in (("neck", "XYZ"), ("head", "QUATERNION"), ("eye.L", "YXZ"), ("eye.R", "AXIS_ANGLE")):
        arm.pose.bones[name].rotation_mode = mode
    return arm


def capture(quick):
    """Issue #24.  ``capture_read_s_<format>_36000`` / ``capture_read_mb_<format>_36000``: reading 36,000
    frames (10 minutes at 60 fps: the shipped Live Link Face take, synthetic head motion added, looped) of each
    format written by ``tools/capture_files.py``, best wall time (of 1 in ``--quick``, else 3; ``capture_read_cpu_s_…``
    the best CPU time, less sensitive to a loaded machine) and the peak of
    traced allocations (numpy and Python objects) during one read.  ``capture_head_eye_vs_live_max_rad``: the
    largest difference between the head / neck / eye bone curves the offline retarget computes from the take's
    CSV and the ones the live path solves from the same rows sent as Live Link Face packets (decoded, resampled
    to the scene's frames as a recorded take is, solved by the live pipeline) — radians (quaternion and
    axis-angle components are unitless)."""
    import tempfile

    import bpy

    from capture_files import WRITERS, load_llf_take, long_take, write_llf_csv
    from shapespace.bridge import assets, retarget
    from shapespace.bridge.live.rig import Pipeline
    from shapespace.core.live import CopySolver, SceneResampler, decode_llf, encode_llf
    from shapespace.core.retarget import read_capture
    out = {}
    folder = tempfile.mkdtemp(prefix="shapespace_capture_")
    csv = os.path.join(ASSETS, "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")
    take = load_llf_take(csv)
    big = long_take(take, 36000)
    for kind, writer in WRITERS.items():
        path = os.path.join(folder, f"take_{kind}.txt")
        with open(path, "w", encoding="utf-8") as fh:
            fh.write(writer(big))
        times = []
        for _ in range(1 if quick else 3):
            cpu, wall = time.process_time(), time.perf_counter()
            read_capture(path)
            times.append((time.perf_counter() - wall, time.process_time() - cpu))
        out[f"capture_read_s_{kind}_36000"] = min(w for w, _ in times)
        out[f"capture_read_cpu_s_{kind}_36000"] = min(c for _, c in times)
        tracemalloc.start()
        read_capture(path)
        out[f"capture_read_mb_{kind}_36000"] = tracemalloc.get_traced_memory()[1] / 1e6
        tracemalloc.stop()
        out[f"capture_file_mb_{kind}_36000"] = os.path.getsize(path) / 1e6
    # head and eyes: offline vs live on the same rows
    assets.load(os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend"))
    ob, arm = bpy.data.objects["FBHead"], _head_eye_rig()
    path = os.path.join(folder, "take_head.csv")
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(write_llf_csv(take))
    bones = retarget.HeadEyeBones(arm.name, "head", "neck", "eye.L", "eye.R", 0.3)
    outcome = retarget.compute_retarget(retarget.read_retarget(ob, path, "copy", bones=bones))
    offline = {(p, i): (x, y) for p, i, _, x, y, _ in outcome.bone_curves}
    specs = retarget.bone_specs(arm, "head", "neck", "eye.L", "eye.R", 0.3)
    solver = CopySolver([(0, 0)], np.ones(1), np.zeros(1), np.zeros(1), np.ones(1), 52)
    live = Pipeline(ob.name, ["EyeBlinkLeft"], solver, 52, "COPY", arm.name, specs)
    scene = bpy.context.scene
    resampler = SceneResampler(scene.render.fps / scene.render.fps_base, scene.frame_start)
    solved = {}
    _, t, w, rot = take
    for k in range(t.size):
        milli = int(round(t[k] * 60000.0))
        frame = decode_llf(encode_llf(np.concatenate([w[k], rot[k]]), milli // 1000, (milli % 1000) / 1000.0))
        for scene_frame, v in resampler.push(frame.time, live.process(frame.vector(), frame.time)):
            solved[scene_frame] = live.solve(v)[1]
    worst = 0.0
    from shapespace.bridge import actions
    for b in specs:
        prop, count = b.channel
        for i in range(count):
            x, y = offline[(actions.bone_path(b.name, prop), i)]
            worst = max(worst, float(np.abs(y - np.array([solved[f][b.name][i] for f in x])).max()))
    out["capture_head_eye_vs_live_max_rad"] = worst
    out["capture_head_eye_frames"] = int(outcome.plan.frames.size)
    return out


def run(quick=False, plot_path=None) -> dict:
    import package
    package.load()
    metrics = speed(quick)
    metrics.update(quality(plot_path))
    metrics.update(landmark_cases())
    metrics.update(key_reduction(quick))
    metrics.update(longtake(quick))
    metrics.update(cancel_latency(quick))
    metrics.update(capture(quick))
    return metrics
