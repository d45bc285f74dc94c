"""Retargeting weight streams (Live Link Face CSV, actions) onto a shape-key rig (thesis 3.5, ch. 5)."""
from __future__ import annotations

import json
import os

import bpy
import numpy as np

from ..core.retarget.capture import read_live_link_csv, resample
from ..core.retarget.cloning import (cloning_matrix, copy_weights, fit_frames, key_poses, reduce_keys, reduce_keys_bezier,
                             spacetime)
from ..core.manipulation.solve import NORMALISED_DIAGONAL
from ..core.names import match_channels
from ..core.result import ShapeSpaceError
from . import actions, shapekeys

METHODS = ("copy", "learned", "perframe", "spacetime")
KEY_POSE_MARKER = "key pose"
NONLINEAR_MESSAGE = ("the target has in-between or combination shapes, so its face is not linear in the sliders: "
                     "fit methods cannot use it; retarget with copy or learned (the driven shapes follow)")
MAPPING_PROP = "shapespace_mapping"


def read_source(path_or_action, scene) -> tuple:
    """A source as ``(names, scene frames, weights)``: a Live Link Face CSV path or an action name.

    CSV timecode (60 fps) is resampled to the scene's frame rate starting at the scene's start frame.
    """
    if isinstance(path_or_action, str) and path_or_action.lower().endswith(".csv"):
        if not os.path.isfile(path_or_action):
            raise ShapeSpaceError(f"file not found: {path_or_action}", "missing_file")
        stream = read_live_link_csv(path_or_action)
        frames, w = resample(stream.times, stream.weights, scene.render.fps, scene.frame_start,
                             scene.render.fps_base)
        return stream.names, frames, w, stream.issues
    action = bpy.data.actions.get(path_or_action) if isinstance(path_or_action, str) else path_or_action
    if action is None:
        raise ShapeSpaceError(f"no CSV file or action named {path_or_action!r}", "missing_source")
    curves = {}
    for fc in _all_fcurves(action):
        path = fc.data_path
        if path.startswith('key_blocks["') and path.endswith('"].value'):
            curves[path[len('key_blocks["'):-len('"].value')]] = fc
    if not curves:
        raise ShapeSpaceError(f"action {action.name!r} animates no shape keys", "no_channels")
    first, last = actions.frame_range(action)
    frames = np.arange(np.ceil(first), np.floor(last) + 1)
    if frames.size < 3:
        raise ShapeSpaceError(f"action {action.name!r} spans {frames.size} frames; at least 3 are needed",
                              "too_short")
    names = sorted(curves)
    w = np.stack([actions.sample_curve(curves[n], frames) for n in names], axis=1)
    return names, frames, w, []


def _all_fcurves(action):
    if not actions.LAYERED:
        return list(action.fcurves)
    out = []
    for slot in action.slots:
        bag = actions._channelbag(action, slot)
        out += list(bag.fcurves) if bag is not None else []
    return out


def channel_mapping(obj, source_names, target_names) -> list:
    """``[(source index, target index, gain, offset)]``: stored overrides first, then name matching."""
    stored = stored_mapping(obj)
    auto, _, _ = match_channels(source_names, target_names)
    claimed = {e.get("target") for name, e in stored.items() if name in source_names}   # overrides win
    out = []
    for i, s in enumerate(source_names):
        if s in stored:
            entry = stored[s]
            if entry.get("target") in target_names:
                out.append((i, target_names.index(entry["target"]), float(entry.get("gain", 1.0)),
                            float(entry.get("offset", 0.0))))
            continue
        if s in auto and auto[s] not in claimed:
            out.append((i, target_names.index(auto[s]), 1.0, 0.0))
    if not out:
        raise ShapeSpaceError("the source and the target share no channels (check the names or the mapping)",
                              "no_mapping")
    return out


def suggest_key_poses(source, scene, count: int = None) -> np.ndarray:
    """Scene frames of the source performance worth posing the target at (Chuang–Bregler: the largest
    and smallest projection on each leading principal component), enough to learn a cloning matrix
    (at least one per moving source channel).  Marks them on the timeline as ``key pose`` markers."""
    names, frames, src, _ = read_source(source, scene)
    moving = np.ptp(src, axis=0) > 1e-6
    need = int(count or moving.sum() + 2)
    X = src[:, moving]
    picks = list(dict.fromkeys(key_poses(X, components=min(int(np.ceil(need / 2)), int(moving.sum())))))
    # extremes repeat across components: top up with the frames farthest from every pose chosen so far
    sq = np.einsum("ij,ij->i", X, X)
    dist = np.sqrt(np.maximum(np.min(sq[:, None] + sq[picks][None] - 2.0 * X @ X[picks].T, axis=1), 0.0))
    while len(picks) < min(need, len(frames)):
        k = int(np.argmax(dist))
        picks.append(k)
        dist = np.minimum(dist, np.linalg.norm(X - X[k], axis=1))
    chosen = np.unique(frames[picks]).astype(int)
    for m in [m for m in scene.timeline_markers if m.name == KEY_POSE_MARKER]:
        scene.timeline_markers.remove(m)
    for f in chosen:
        scene.timeline_markers.new(KEY_POSE_MARKER, frame=int(f))
    return chosen


def _learned_weights(obj, model, frames, src, key_pose_action, report) -> np.ndarray:
    """Linear expression cloning (3.5.3): fit ``W_t ≈ W_s E`` to the artist's key poses — the target's
    shape-key values keyed in ``key_pose_action`` — against the source at the same frames, then map
    every frame.  Needs at least as many key poses as moving source channels."""
    if key_pose_action is None:
        raise ShapeSpaceError("the learned method needs the target posed at key frames: key the target's "
                              "shape keys at the suggested key poses in an action and choose it", "no_key_poses")
    action = (bpy.data.actions.get(key_pose_action) if isinstance(key_pose_action, str) else key_pose_action)
    curves = actions.shape_key_curves(obj, action) if action is not None else {}
    if not curves:
        raise ShapeSpaceError(f"key-pose action {key_pose_action!r} keys none of {obj.name!r}'s shape keys",
                              "no_key_poses")
    keyed = np.unique(np.concatenate([actions.read_curve(fc)[0] for fc in curves.values()]))
    keyed = keyed[(keyed >= frames[0]) & (keyed <= frames[-1])]
    moving = np.ptp(src, axis=0) > 1e-6
    Ws = np.column_stack([np.interp(keyed, frames, src[:, i]) for i in np.flatnonzero(moving)])
    Wt = actions.sample_shape_keys(obj, model.names, keyed, action)
    E = cloning_matrix(Ws, Wt)
    report.update({"key_poses": int(keyed.size), "learned_fit_rms": float(np.sqrt(np.mean((Ws @ E - Wt) ** 2)))})
    return src[:, moving] @ E


LAST_PROP = "shapespace_last_retarget"
REPORT_KEYS = ("source", "method", "frames", "mapped_channels", "position_error_rms", "velocity_error_rms",
               "clipping_frames", "keys_kept_frac", "converged", "action", "previous_action")


def _remember(obj, report, previous) -> None:
    """Keep the last retarget's report (and the action it replaced) on the Key, for the panel and Discard."""
    report["previous_action"] = previous.name if previous is not None else ""
    obj.data.shape_keys[LAST_PROP] = json.dumps({k: report[k] for k in REPORT_KEYS if k in report})


def last_report(obj) -> dict:
    key = obj.data.shape_keys if obj is not None and obj.type == "MESH" else None
    return json.loads(key.get(LAST_PROP, "{}")) if key is not None else {}


def discard_last(obj) -> str:
    """Undo the last retarget's result: give the rig back the action it played before and delete the
    retargeted action if nothing else uses it.  Returns the restored action's name ('' for none)."""
    rep = last_report(obj)
    if not rep:
        raise ShapeSpaceError(f"{obj.name!r} has no retarget result to discard", "no_result")
    key = obj.data.shape_keys
    made = bpy.data.actions.get(rep.get("action", ""))
    previous = bpy.data.actions.get(rep.get("previous_action", ""))
    if previous is not None:
        actions.assign_action(key, previous)
    elif key.animation_data is not None:
        key.animation_data.action = None
    if made is not None and made.users == 0:
        bpy.data.actions.remove(made)
    del key[LAST_PROP]
    return previous.name if previous is not None else ""


def stored_mapping(obj) -> dict:
    """The channel-mapping overrides stored on ``obj``'s shape keys: ``{source: {target, gain, offset}}``."""
    key = obj.data.shape_keys
    return json.loads(key.get(MAPPING_PROP, "{}")) if key is not None else {}


def remove_mapping(obj, source: str) -> None:
    """Drop the override of ``source`` (name matching applies again)."""
    data = stored_mapping(obj)
    if source not in data:
        raise ShapeSpaceError(f"{obj.name!r} has no mapping override for {source!r}", "missing_channel")
    del data[source]
    obj.data.shape_keys[MAPPING_PROP] = json.dumps(data, sort_keys=True)


def set_mapping(obj, source: str, target: str, gain: float = 1.0, offset: float = 0.0) -> None:
    """Store a channel mapping override (kept in the .blend on the shape-key datablock)."""
    key = obj.data.shape_keys
    if not source:
        raise ShapeSpaceError("name the source channel", "missing_channel")
    if key is None or target not in key.key_blocks or target == key.reference_key.name:
        raise ShapeSpaceError(f"{obj.name!r} has no shape key {target!r} to map to", "missing_key")
    data = json.loads(key.get(MAPPING_PROP, "{}"))
    data[source] = {"target": target, "gain": float(gain), "offset": float(offset)}
    key[MAPPING_PROP] = json.dumps(data, sort_keys=True)


def retarget(obj, source, method: str = "spacetime", scene=None, lam: float = 1e-7, key_tolerance: float = 0.0,
             action_name: str = None, key_shape: str = "BEZIER", key_pose_action=None) -> dict:
    """Retarget ``source`` onto ``obj``'s sliders and write a new action; returns a report dict."""
    if method not in METHODS:
        raise ShapeSpaceError(f"method must be one of {', '.join(METHODS)}, got {method!r}", "method")
    scene = scene or bpy.context.scene
    model = shapekeys.read_blendshape_model(obj)
    if not model.is_linear and method in ("perframe", "spacetime"):
        raise ShapeSpaceError(NONLINEAR_MESSAGE, "nonlinear")
    names, frames, src, issues = read_source(source, scene)
    lo, hi = model.slider_min, model.slider_max
    report = {"source": str(source), "method": method, "frames": int(frames.size),
              "issues": [i.message for i in issues]}
    if method == "learned":     # the artist's key poses define the map: no channel names needed
        raw = _learned_weights(obj, model, frames, src, key_pose_action, report)  # unbounded ideal
        report["mapped_channels"] = int(np.sum(np.ptp(src, axis=0) > 1e-6))
    else:
        mapping = channel_mapping(obj, names, model.names)
        gain = np.ones(model.n_targets)
        offset = np.zeros(model.n_targets)
        for _, j, g, o in mapping:
            gain[j], offset[j] = g, o
        pairs = [(i, j) for i, j, _, _ in mapping]
        raw = copy_weights(src, pairs, model.n_targets, gain, offset)             # unbounded ideal
        report["mapped_channels"] = len(pairs)
    if method in ("copy", "learned"):
        W = np.clip(raw, lo, hi)
    else:
        # the source performance as geometry on the target: the copied weights without limits, in
        # size-normalised units (the model's diagonal measures 30) so λ means the same for any rig
        unit = (model.scale or NORMALISED_DIAGONAL) / NORMALISED_DIAGONAL
        B = model.delta_matrix / unit
        b0 = model.neutral.ravel() / unit
        S = b0 + raw @ B.T
        if method == "perframe":
            W = fit_frames(B, b0, S, lo, hi)
        else:
            sigma = np.maximum(raw.std(axis=0), 0.05 * (hi - lo))
            res = spacetime(B, b0, S, sigma, lam, lo=lo, hi=hi, relative=True)
            W = res.weights
            report["solver_iterations"] = res.iterations
            report["status"] = res.message
            report["converged"] = res.status == 0
    # errors against the ideal (unlimited) performance, at every vertex, relative to the model size
    pos_err = np.linalg.norm((W - raw) @ model.delta_matrix.T, axis=1)
    vel = np.diff(W - raw, axis=0) @ model.delta_matrix.T
    report["position_error_rms"] = float(np.sqrt(np.mean(pos_err ** 2)) / model.scale)
    report["velocity_error_rms"] = float(np.sqrt(np.mean(np.sum(vel ** 2, axis=1))) / model.scale)
    report["clipping_frames"] = int(np.sum(np.any((raw < lo - 1e-9) | (raw > hi + 1e-9), axis=1)))
    return _write_result(obj, model.names, frames, W, action_name or f"{obj.name}_{method}", key_tolerance,
                         key_shape, report)


KEY_SHAPES = ("BEZIER", "LINEAR")


def _check_key_shape(key_shape: str) -> None:
    if key_shape not in KEY_SHAPES:
        raise ShapeSpaceError(f"key shape must be one of {', '.join(KEY_SHAPES)}, got {key_shape!r}", "key_shape")


def _write_result(obj, names, frames, W, action_name, key_tolerance, key_shape, report) -> dict:
    """Key ``W`` (f, n) into a new action on ``obj`` — every frame, or the fewest keys within
    ``key_tolerance`` — and remember the report and the action it replaces (for Discard Result)."""
    _check_key_shape(key_shape)                       # before anything is written
    key = obj.data.shape_keys
    previous = actions.active_action(key)
    if key_tolerance > 0:
        action = actions.new_action(key, action_name)
        report["keys_kept_frac"] = reduce_action_keys(obj, names, frames, W, key_tolerance, key_shape)
    else:
        action = actions.key_shape_values(obj, names, frames, W, action_name)
    report["action"] = action.name
    _remember(obj, report, previous)
    return report


def reduce_action_keys(obj, names, frames, W, tolerance: float, key_shape: str = "BEZIER") -> float:
    """Rewrite the dense curves ``W`` (f, n) of ``names`` with the fewest keys within ``tolerance``
    (smooth Bézier keys, or linear ones); returns the fraction of keys kept."""
    _check_key_shape(key_shape)
    key = obj.data.shape_keys
    kept = 0
    for j, name in enumerate(names):
        path = actions.shape_key_path(name)
        if key_shape == "BEZIER":
            idx, key_values, slopes = reduce_keys_bezier(frames, W[:, j], tolerance)
            actions.write_bezier_curve(key, path, frames[idx], key_values, slopes)
        else:
            idx = reduce_keys(frames, W[:, j], tolerance)
            actions.write_curve(key, path, frames[idx], W[idx, j])
        kept += idx.size
    return kept / max(frames.size * len(names), 1)


# ------------------------------------------------------------------ dense performances (mesh sequences)
LANDMARK_PREFIX = "lm_"
STABLE_GROUP = "stable"


def _group_vertices(obj, name):
    from .meshes import group_weight_vector
    w = group_weight_vector(obj, name)
    return np.flatnonzero(w > 0) if w is not None else np.zeros(0, dtype=int)


def landmark_pairs(source, target):
    """Corresponding vertices from vertex groups named ``lm_<name>`` on both meshes (one vertex each)."""
    names = sorted(g.name for g in source.vertex_groups if g.name.startswith(LANDMARK_PREFIX)
                   and g.name in target.vertex_groups)
    src, dst = [], []
    for n in names:
        a, b = _group_vertices(source, n), _group_vertices(target, n)
        if a.size and b.size:
            src.append(int(a[0]))
            dst.append(int(b[0]))
    return np.array(src, dtype=int), np.array(dst, dtype=int)


def mesh_sequence(source, scene, frames) -> np.ndarray:
    """Evaluated (object-space) positions of ``source`` at each frame, (f, p, 3)."""
    from .meshes import evaluated_positions
    current = scene.frame_current
    depsgraph = bpy.context.evaluated_depsgraph_get()
    out = []
    try:
        for f in frames:
            scene.frame_set(int(f))
            out.append(evaluated_positions(source, depsgraph).astype(np.float64))
    finally:
        scene.frame_set(current)
    return np.stack(out)


def dense_source_positions(source, target_model, target, scene, frames):
    """The source performance transferred onto the target's vertices: (f, p_t·3) positions and the rows used.

    Same topology: vertex-to-vertex, the motion rotated and scaled by the similarity between the source's
    rest (its reference shape key, else its mesh vertices — for a cache, as imported) and the target's
    neutral.  Otherwise landmarks (``lm_*`` groups on both meshes, ≥ 3): the source neutral is warped
    onto the target neutral (similarity + thin-plate), every target vertex takes its
    closest warped source vertex, and the source's motion is carried over rotated and scaled by the
    landmarks' similarity.  A ``stable`` vertex group on the source removes head motion per frame
    (rigid Procrustes onto the neutral).
    """
    from ..core.retarget.cloning import check_landmarks, closest_points, landmark_warp, procrustes
    from .arrays import read_float
    from .meshes import vertex_positions
    seq = mesh_sequence(source, scene, frames)
    key = source.data.shape_keys
    # the source's neutral: its reference shape key, or its undeformed vertices
    rest = (read_float(key.reference_key.data, "co", 3) if key is not None else
            vertex_positions(source.data)).astype(np.float64)
    stable = _group_vertices(source, STABLE_GROUP)
    if stable.size >= 3:
        for i in range(1, seq.shape[0]):
            s, R, t = procrustes(seq[i][stable], rest[stable], scaling=False)
            seq[i] = seq[i] @ R.T + t
    motion = seq - rest
    neutral_t = target_model.neutral
    if seq.shape[1] == neutral_t.shape[0] and not len(landmark_pairs(source, target)[0]):
        # same topology: vertex to vertex, the motion carried by the similarity that takes the source's
        # rest onto the target's neutral (the source may live in another space, e.g. a world-space cache)
        corr = np.arange(neutral_t.shape[0])
        scale, R, _ = procrustes(rest, neutral_t)
    else:
        src_lm, dst_lm = landmark_pairs(source, target)
        if src_lm.size < 3:
            raise ShapeSpaceError(f"different meshes need at least 3 landmark pairs (vertex groups named "
                                  f"'{LANDMARK_PREFIX}…' on both); found {src_lm.size}", "too_few_landmarks")
        moved = np.linalg.norm(target_model.deltas, axis=2).max(axis=0) > 1e-6 * (target_model.scale or 1.0)
        if not moved[dst_lm].any():
            raise ShapeSpaceError(f"all {dst_lm.size} landmarks lie on target vertices no shape key moves: place "
                                  "some on the moving face (mouth corners, lids, chin)", "static_landmarks")
        check_landmarks(rest[src_lm], neutral_t[dst_lm])
        scale, R, _ = procrustes(rest[src_lm], neutral_t[dst_lm])
        warped = landmark_warp(rest[src_lm], neutral_t[dst_lm], rest)
        corr, _ = closest_points(neutral_t, warped)
    carried = scale * motion[:, corr, :] @ R.T
    return (neutral_t[None] + carried).reshape(len(frames), -1)


def retarget_dense(obj, source_obj, method: str = "spacetime", scene=None, lam: float = 1e-7,
                   key_tolerance: float = 0.0, action_name: str = None, key_shape: str = "BEZIER") -> dict:
    """Retarget an animated mesh (any deformation) onto ``obj``'s sliders by geometric fitting."""
    if method not in ("perframe", "spacetime"):
        raise ShapeSpaceError("a mesh performance needs a geometric method: perframe or spacetime", "method")
    scene = scene or bpy.context.scene
    model = shapekeys.read_blendshape_model(obj)
    if not model.is_linear:
        raise ShapeSpaceError(NONLINEAR_MESSAGE, "nonlinear")
    frames = np.arange(scene.frame_start, scene.frame_end + 1, dtype=np.float64)
    if frames.size < 3:
        raise ShapeSpaceError(f"the scene range has {frames.size} frames; at least 3 are needed", "too_short")
    S = dense_source_positions(source_obj, model, obj, scene, frames)
    unit = (model.scale or NORMALISED_DIAGONAL) / NORMALISED_DIAGONAL
    B = model.delta_matrix / unit
    b0 = model.neutral.ravel() / unit
    lo, hi = model.slider_min, model.slider_max
    ideal = fit_frames(B, b0, S / unit, np.full(model.n_targets, -10.0), np.full(model.n_targets, 10.0))
    report = {"clipping_frames": int(np.sum(np.any((ideal < lo - 1e-6) | (ideal > hi + 1e-6), axis=1)))}
    if method == "perframe":
        W = fit_frames(B, b0, S / unit, lo, hi)
    else:
        sigma = np.maximum(ideal.std(axis=0), 0.05 * (hi - lo))
        res = spacetime(B, b0, S / unit, sigma, lam, lo=lo, hi=hi, relative=True)
        W = res.weights
        report.update({"solver_iterations": res.iterations, "status": res.message, "converged": res.status == 0})
    residual = ((b0 + W @ B.T) * unit - S).reshape(len(frames), -1, 3)         # fit − source, per vertex
    vel = np.diff(residual, axis=0)
    report.update({"source": source_obj.name, "method": method, "frames": int(frames.size),
                   "position_error_rms": float(np.sqrt(np.mean(np.sum(residual ** 2, axis=(1, 2)))) / model.scale),
                   "velocity_error_rms": float(np.sqrt(np.mean(np.sum(vel ** 2, axis=(1, 2)))) / model.scale),
                   "issues": []})
    return _write_result(obj, model.names, frames, W, action_name or f"{obj.name}_{source_obj.name}",
                         key_tolerance, key_shape, report)


def add_landmark(obj, name: str, vertex: int) -> str:
    """(Re)define the landmark vertex group ``lm_<name>`` as the single vertex ``vertex``."""
    group_name = name if name.startswith(LANDMARK_PREFIX) else LANDMARK_PREFIX + name
    group = obj.vertex_groups.get(group_name) or obj.vertex_groups.new(name=group_name)
    group.remove(list(range(len(obj.data.vertices))))
    group.add([int(vertex)], 1.0, "REPLACE")
    return group.name


def landmarks_from_shapes(source, target) -> list:
    """Create landmark pairs from the shapes both meshes share (by mapped name): each pair's vertices are
    the ones that shape moves most on each mesh (chin for jawOpen, lids for eyeBlink, …).  Existing
    ``lm_auto_*`` groups are replaced; hand-placed landmarks are kept.  Returns the group names."""
    from ..core.retarget.cloning import peak_landmarks
    for ob in (source, target):
        if ob.type != "MESH" or ob.data.shape_keys is None or len(ob.data.shape_keys.key_blocks) < 2:
            raise ShapeSpaceError(f"{ob.name!r} has no shape keys to find landmarks from", "no_shape_keys")
    model_s = shapekeys.read_blendshape_model(source)
    model_t = shapekeys.read_blendshape_model(target)
    mapping = channel_mapping(target, model_s.names, model_t.names)
    src, dst, used = peak_landmarks(model_s.deltas, model_t.deltas, [(i, j) for i, j, _, _ in mapping])
    if src.size < 3:
        raise ShapeSpaceError(f"only {src.size} shared shapes have a clear peak vertex; place landmarks by hand",
                              "too_few_landmarks")
    for ob in (source, target):
        for group in [g for g in ob.vertex_groups if g.name.startswith(LANDMARK_PREFIX + "auto_")]:
            ob.vertex_groups.remove(group)
    names = []
    for a, b, (_, j) in zip(src, dst, used):
        name = "auto_" + model_t.names[j]
        add_landmark(source, name, int(a))
        names.append(add_landmark(target, name, int(b)))
    return names


def selected_vertex(obj):
    """The single selected vertex of a mesh (object mode data), or None."""
    sel = np.zeros(len(obj.data.vertices), dtype=bool)
    obj.data.vertices.foreach_get("select", sel)
    idx = np.flatnonzero(sel)
    return int(idx[0]) if idx.size == 1 else None
