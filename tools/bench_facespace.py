"""Covariance inpainting benchmark (thesis 9.3): fill held-out gaps of real animation curves.

A gap of G frames is cut out of a real curve and filled by

- ``blender``: Blender's own interpolation across the gap, evaluated by Blender — the keys inside
  the gap are deleted from a copy of the action, ``FCurve.update()`` recalculates the auto-clamped
  handles and ``FCurve.evaluate`` is called at the gap frames.  The BVH importer keys LINEAR
  interpolation; ``blender`` switches the keys to BEZIER first (Blender's default for keys an
  animator inserts), ``blender_imported`` keeps the curve as imported;
- ``ours_single``: ``core.facespace.inpaint_curve`` on that channel alone;
- ``ours_multi``: superresolution — the channel plus related channels that stay known through the
  gap (per-channel mask), so the other channels predict the missing one;
- ``linear`` / ``cubic``: ``core.facespace.linear_fill`` / ``cubic_fill`` references.

Errors are the RMS over the gap's frames, averaged over the held-out gaps (deterministic positions;
40 per knee, 20 on the face, 6 each with ``--quick``).  ``..._wins_frac_...`` is the fraction of gaps
where ``ours_multi`` beats ``blender``, ``..._median_...`` the ratio of the median
per-gap errors (the walk has held poses where the knee is exactly straight: Blender's clamped
handles reproduce those with zero error).
Data: the knee flexion channels of the CMU walk 131_01.bvh (120 fps; degrees) and jawOpen of the
vendored Face Cap capture sampled on integer frames (weights).
"""
from __future__ import annotations

import os
import time

import numpy as np

import env
from bench_support import ASSETS, SHARED, shared_data  # noqa: E402

MOCAP = os.path.join(SHARED, "cmu_mocap", "131_01.bvh")
FACECAP = os.path.join(env.ROOT, "assets", "facecap", "facecap_decoded.glb")
KNEE_GAPS = (10, 20, 40)
FACE_GAPS = (6, 12)


# knee, hip bone names as the BVH importer names them (CMU / cgspeed and the common "Leg/UpLeg" style)
KNEE_NAMES = {"Left": ("LeftKnee", "LeftLeg"), "Right": ("RightKnee", "RightLeg")}
HIP_NAMES = {"Left": ("LeftHip", "LeftUpLeg"), "Right": ("RightHip", "RightUpLeg")}
# jawOpen and the shapes the jaw drags along (ARKit): chosen by anatomy, not tuned on the gaps
FACE_CHANNELS = ("jawOpen", "mouthLowerDown_L", "mouthLowerDown_R", "mouthClose")
METHODS = ("blender", "ours_single", "ours_multi", "ours_auto", "linear", "cubic")


def _bone(arm, candidates):
    for name in candidates:
        if name in arm.pose.bones:
            return name
    raise KeyError(f"none of {candidates} in {arm.name}")


def _find(action, id_block, path, index):
    from shapespace.bridge import actions
    return next(fc for fc in actions.fcurves(action, id_block) if fc.data_path == path and fc.array_index == index)


def blender_fill(id_block, action, path, index, gap_frames, bezier=True) -> np.ndarray:
    """Blender's interpolation across ``gap_frames``: delete the keys inside the gap on a copy of
    ``action`` and let Blender evaluate the curve there.  ``bezier`` sets BEZIER interpolation on
    every key of the copy first (handles stay AUTO_CLAMPED, recalculated by ``update``)."""
    import bpy
    gap_frames = np.asarray(gap_frames, dtype=np.float64)
    copy = action.copy()
    try:
        fc = _find(copy, id_block, path, index)
        pts = fc.keyframe_points
        if bezier:
            code = bpy.types.Keyframe.bl_rna.properties["interpolation"].enum_items["BEZIER"].value
            pts.foreach_set("interpolation", np.full(len(pts), code, dtype=np.int32))
        co = np.empty(2 * len(pts), dtype=np.float32)
        pts.foreach_get("co", co)
        kx = co[0::2].astype(np.float64)
        inside = np.flatnonzero((kx >= gap_frames[0] - 1e-3) & (kx <= gap_frames[-1] + 1e-3))
        for i in inside[::-1]:
            pts.remove(pts[int(i)])
        fc.update()
        return np.array([fc.evaluate(float(f)) for f in gap_frames], dtype=np.float64)
    finally:
        bpy.data.actions.remove(copy)


def _positions(seed, T, G, n):
    """``n`` deterministic gap starts, each with at least 2 G known frames before and after."""
    rng = np.random.default_rng(seed)
    return np.sort(rng.choice(np.arange(2 * G, T - 3 * G), size=n, replace=False))


def _fills(X, s, G, pool=None):
    """Our fills of channel 0 of ``X`` (T, c) over [s, s + G); also timing and the known-sample check.
    ``ours_auto`` is what the Inpaint Gap operator does: channel 0 plus the curves of ``pool`` (T, C)
    that :func:`context_channels` picks (all curves of the action are candidates)."""
    from shapespace.core import facespace as facestats
    T = X.shape[0]
    known = np.ones(T, dtype=bool)
    known[s:s + G] = False
    mask = np.ones(X.shape, dtype=bool)
    mask[s:s + G, 0] = False
    single = facestats.inpaint_curve(X[:, 0], known).value
    t = time.perf_counter()
    multi = facestats.inpaint_curve(X, mask).value
    dt = time.perf_counter() - t
    exact = max(float(np.abs(single[known] - X[known, 0]).max()), float(np.abs(multi[mask] - X[mask]).max()))
    P = np.column_stack([X[:, :1], X[:, :0] if pool is None else pool])
    chosen = facestats.context_channels(P, 0, known, G)
    auto_mask = np.ones((T, chosen.size), dtype=bool)
    auto_mask[s:s + G, 0] = False
    auto = facestats.inpaint_curve(P[:, chosen], auto_mask).value[:, 0]
    return {"ours_single": single[s:s + G], "ours_multi": multi[s:s + G, 0], "ours_auto": auto[s:s + G],
            "linear": facestats.linear_fill(X[:, 0], known)[s:s + G],
            "cubic": facestats.cubic_fill(X[:, 0], known)[s:s + G]}, dt, exact


def mocap(quick):
    """Knee flexion channels of the CMU walk: every method on the same held-out gaps, degrees."""
    import bpy

    from shapespace.bridge import actions, assets
    assets.load(MOCAP)
    arm = next(ob for ob in bpy.data.objects if ob.type == "ARMATURE")
    action = actions.active_action(arm)
    curves = {(fc.data_path, fc.array_index): fc for fc in actions.fcurves(action, arm)}

    def rot(bone, i):
        return curves[(actions.bone_path(bone, "rotation_euler"), i)]

    kx = actions.read_curve(rot(_bone(arm, KNEE_NAMES["Left"]), 0))[0]
    frames = np.arange(kx[0], kx[-1] + 1)                         # one key per BVH frame
    sample = lambda fc: actions.sample_curve(fc, frames)           # noqa: E731  (radians)
    knees, hips = {}, {}
    for side in ("Left", "Right"):
        knee, hip = _bone(arm, KNEE_NAMES[side]), _bone(arm, HIP_NAMES[side])
        axis = int(np.argmax([np.ptp(sample(rot(knee, i))) for i in range(3)]))   # flexion: largest range
        knees[side] = (knee, axis)
        hips[side] = hip
    out = {"inpaint_mocap_frames": float(frames.size)}
    n = 6 if quick else 40                                        # gaps per knee
    example = []
    exact = 0.0
    for G in KNEE_GAPS:
        errs = {m: [] for m in METHODS + ("blender_imported",)}
        times = []
        for side, other in (("Left", "Right"), ("Right", "Left")):
            knee, axis = knees[side]
            path = actions.bone_path(knee, "rotation_euler")
            chans = [rot(knee, axis)] + [rot(hips[side], i) for i in range(3)] + \
                    [rot(hips[other], i) for i in range(3)] + [rot(knees[other][0], knees[other][1])]
            X = np.column_stack([sample(fc) for fc in chans])
            pool = np.column_stack([sample(fc) for fc in curves.values() if fc is not chans[0]
                                    and (fc.data_path, fc.array_index) != (path, axis)])
            for s in _positions(1000 * G + (side == "Right"), frames.size, G, n):
                truth = X[s:s + G, 0]
                fills, dt, ex = _fills(X, s, G, pool)
                fills["blender"] = blender_fill(arm, action, path, axis, frames[s:s + G], bezier=True)
                fills["blender_imported"] = blender_fill(arm, action, path, axis, frames[s:s + G], bezier=False)
                times.append(dt)
                exact = max(exact, ex)
                for m, v in fills.items():
                    errs[m].append(float(np.degrees(np.sqrt(np.mean((v - truth) ** 2)))))
                if G == 20:
                    lo, hi = s - 2 * G, s + 3 * G
                    example.append((errs["blender"][-1], f"{knee} rotation_euler[{axis}], frames {int(frames[s])}"
                                    f"–{int(frames[s + G - 1])}", frames[lo:hi], np.degrees(X[lo:hi, 0]),
                                    frames[s - 1:s + G + 1], {m: np.degrees(v) for m, v in fills.items()},
                                    np.degrees(X[[s - 1, s + G], 0])))
        for m, e in errs.items():
            out[f"inpaint_rms_deg_{m}_gap{G}"] = float(np.mean(e))
        out[f"inpaint_ours_over_blender_gap{G}"] = out[f"inpaint_rms_deg_ours_auto_gap{G}"] / \
            out[f"inpaint_rms_deg_blender_gap{G}"]
        out[f"inpaint_ours_over_blender_median_gap{G}"] = float(np.median(errs["ours_auto"]) /
                                                                          np.median(errs["blender"]))
        out[f"inpaint_ours_auto_wins_frac_gap{G}"] = float(np.mean(np.array(errs["ours_auto"]) <
                                                                    np.array(errs["blender"])))
        out[f"inpaint_ms_multi_gap{G}"] = float(np.mean(times) * 1e3)
    out["inpaint_known_max_abs_diff"] = exact                     # radians: known samples reproduced
    example.sort(key=lambda e: e[0])
    return out, example[len(example) // 2]                        # the gap with the median Blender error


def facecap(quick):
    """jawOpen of the Face Cap capture on integer frames: Blender vs ours on held-out gaps, weights."""
    import bpy

    from shapespace.bridge import actions, assets
    assets.load(FACECAP)
    ob = bpy.data.objects["Mesh_2"]
    curves = actions.shape_key_curves(ob)
    kx = actions.read_curve(curves[FACE_CHANNELS[0]])[0]         # keys on fractional frames (30 → 24 fps)
    frames = np.arange(np.ceil(kx[0]), np.floor(kx[-1]) + 1)
    X = actions.sample_shape_keys(ob, list(FACE_CHANNELS), frames)
    others = [n for n in curves if n != FACE_CHANNELS[0]]
    pool = actions.sample_shape_keys(ob, others, frames)
    # the dense integer-frame curve as an animator would key it (Bezier, auto-clamped handles)
    dense = actions.key_shape_values(ob, [FACE_CHANNELS[0]], frames, X[:, :1], action_name="jawOpen_dense",
                                     interpolation="BEZIER")
    key = ob.data.shape_keys
    path = actions.shape_key_path(FACE_CHANNELS[0])
    out = {"inpaint_facecap_frames": float(frames.size)}
    n = 6 if quick else 20
    exact = 0.0
    for G in FACE_GAPS:
        errs = {m: [] for m in METHODS}
        for s in _positions(7000 + G, frames.size, G, n):
            truth = X[s:s + G, 0]
            fills, _, ex = _fills(X, s, G, pool)
            fills["blender"] = blender_fill(key, dense, path, 0, frames[s:s + G], bezier=True)
            exact = max(exact, ex)
            for m, v in fills.items():
                errs[m].append(float(np.sqrt(np.mean((v - truth) ** 2))))
        for m, e in errs.items():
            out[f"inpaint_rms_{m}_facecap_gap{G}"] = float(np.mean(e))
        out[f"inpaint_ours_over_blender_facecap_gap{G}"] = out[f"inpaint_rms_ours_auto_facecap_gap{G}"] / \
            out[f"inpaint_rms_blender_facecap_gap{G}"]
    out["inpaint_facecap_known_max_abs_diff"] = exact
    return out


def plot(metrics, example, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    _, title, fx, fy, gx, fills, ends = example
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 3.8), gridspec_kw={"width_ratios": [1.5, 1]})
    ax.axvspan(gx[0], gx[-1], color="0.92", label="held-out gap")
    ax.plot(fx, fy, "k-", lw=1.6, label="truth (capture)")
    for m, style, label in (("blender", "C3--", "Blender Bézier (keys deleted)"),
                            ("linear", "C7:", "linear"), ("ours_single", "C0-.", "ours, knee only"),
                            ("ours_multi", "C2-", "ours, knee + hips + other knee"),
                            ("ours_auto", "C1-", "ours, curves chosen automatically (the operator)")):
        ax.plot(gx, np.concatenate([ends[:1], fills[m], ends[1:]]), style, lw=1.6, label=label)
    ax.set_title(f"CMU 131_01 {title}", fontsize=9)
    ax.set_xlabel("frame (120 fps)")
    ax.set_ylabel("knee flexion (degrees)")
    ax.legend(fontsize=7)
    for m, style, label in (("blender", "C3s--", "Blender Bézier"), ("linear", "C7o:", "linear"),
                            ("cubic", "C1^:", "cubic spline"), ("ours_single", "C0d-.", "ours, knee only"),
                            ("ours_multi", "C2o-", "ours, multi-channel")):
        bx.plot(KNEE_GAPS, [metrics[f"inpaint_rms_deg_{m}_gap{G}"] for G in KNEE_GAPS], style, label=label)
    bx.set_xscale("log", base=2)
    bx.set_yscale("log")
    bx.set_xticks(KNEE_GAPS, [str(G) for G in KNEE_GAPS])
    bx.set_xlabel("gap length (frames)")
    bx.set_ylabel("mean RMS error over held-out gaps (degrees)")
    bx.set_title("knee flexion, both knees", fontsize=9)
    bx.grid(True, which="both", alpha=0.3)
    bx.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def representations():
    """Face Cap (52 targets) and ICT FaceKit (57) driven by the Face Cap capture: PCA components needed
    at 1e-3 / 1e-2 of the head size, coherence, sparsity, the face prior, and shell vs linear in-betweens
    of every pair of ten expressive captured frames (norm at the midpoint relative to the endpoints')."""
    import bpy

    from shapespace.bridge import actions, assets, facespace, retarget, shapekeys
    from shapespace.core import facespace as fs
    from shapespace.core.retarget.cloning import copy_weights
    out = {}
    assets.load(os.path.join(ASSETS, "facecap", "facecap_decoded.glb"))
    head = bpy.data.objects["Mesh_2"]
    capture = actions.active_action(head.data.shape_keys)
    model = shapekeys.read_blendshape_model(head)
    W, frames = facespace.animation_weights(head, model.names, capture)
    rigs = {"facecap": (model, W)}
    ict_path = shared_data(os.path.join("ict_facekit", "ict_facekit_expressions.glb"), "the ICT FaceKit rig")
    if ict_path:
        assets.load(ict_path, replace=False)
        ict = bpy.data.objects["ICTFace"]
        ict_model = shapekeys.read_blendshape_model(ict)
        pairs = [(i, j) for i, j, _, _ in retarget.channel_mapping(ict, model.names, ict_model.names)]
        rigs["ict"] = (ict_model, np.clip(copy_weights(W, pairs, ict_model.n_targets), 0, 1))
    for name, (m, Wr) in rigs.items():
        for tol in (1e-3, 1e-2):
            rep = fs.compression_report(m, Wr, tol * m.scale)
            out[f"pca_components_{name}_tol{tol:g}"] = rep.value
            out[f"compression_ratio_{name}_tol{tol:g}"] = rep.diagnostics["compression_ratio"]
        out[f"mutual_coherence_{name}"] = fs.mutual_coherence(m)
        out[f"empty_targets_{name}"] = len(fs.empty_targets(m))
        sp = fs.sparsity_comparison(m, Wr).value
        for form in ("blendshape", "pca"):
            out[f"idle_fraction_{form}_{name}"] = sp[form]["curve_small_fraction"]
            out[f"hoyer_rms_{form}_{name}"] = sp[form]["hoyer_rms"]
    g = fs.fit_face_gaussian(W)
    out["prior_dimension_facecap"] = g.dimension
    norms = g.face_norm(W)
    out["prior_mean_face_norm"] = float(g.face_norm(W.mean(axis=0)))
    out["prior_median_frame_norm"] = float(np.median(norms))
    out["prior_shell_radius"] = g.shell_radius
    picks = np.argsort(norms)[-10:]
    ratios = {"shell": [], "linear": []}
    for a in range(10):
        for b in range(a + 1, 10):
            w0, w1 = W[picks[a]], W[picks[b]]
            ends = 0.5 * (norms[picks[a]] + norms[picks[b]])
            ratios["shell"].append(float(g.face_norm(fs.shell_interpolate(g, w0, w1, [0.5]))[0]) / ends)
            ratios["linear"].append(float(g.face_norm(fs.linear_interpolate(w0, w1, [0.5]))[0]) / ends)
    for k, v in ratios.items():
        out[f"midpoint_norm_over_ends_{k}"] = float(np.mean(v))
    return out


def run(quick=False, plot_path=None) -> dict:
    import package
    package.load()
    t = time.perf_counter()
    if shared_data(os.path.join("cmu_mocap", "131_01.bvh"), "the CMU walk (mocap) case and the plot"):
        metrics, example = mocap(quick)
    else:
        metrics, example, plot_path = {}, None, None
    metrics.update(facecap(quick))
    metrics["inpaint_bench_s"] = time.perf_counter() - t
    metrics.update(representations())
    if plot_path:
        plot(metrics, example, plot_path)
    return metrics
