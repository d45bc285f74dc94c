"""Face-space tools in Blender (thesis 3.7, ch. 6, 9): rig conversions, diagnostics, the face prior,
shell in-betweens, curve inpainting and pose-space confidence.

Everything here reads Blender data through the other bridge modules, calls :mod:`core.facespace` /
:mod:`core.facespace.stats`, and writes *new* keys, objects, images or actions — the user's shape keys are
only changed by the operators that say so (filling frames, inpainting a gap).
"""
from __future__ import annotations

import json
import os

import bpy
import numpy as np

from ..core.facespace import forms as fs
from ..core.facespace import stats as facestats
from ..core.posespace import confidence as gpconf
from ..core.result import ShapeSpaceError
from . import actions, shapekeys
from .arrays import write_float

REPRESENTATION_PROP = "shapespace_representation"
PRIOR_PROP = "shapespace_face_prior"
ANALYSIS_PROP = "shapespace_analysis"
NEUTRAL_KEY = "Neutral"
ZERO_KEY = "Zero"


# ------------------------------------------------------------------ shared readers
def linear_model(obj):
    """The rig as a :class:`BlendshapeModel`, refusing in-betweens and combinations (correctives are
    not faces: representations and statistics are about the primary sliders)."""
    model = shapekeys.read_blendshape_model(obj)
    if not model.is_linear:
        raise ShapeSpaceError("the rig has in-between or combination shapes: face-space tools work on its "
                              "primary sliders only; use a copy without them", "nonlinear")
    if model.n_targets == 0:
        raise ShapeSpaceError(f"{obj.name!r} has no shape keys besides its reference key", "no_targets")
    return model


def animation_weights(obj, names, action=None):
    """Values of the shape keys ``names`` in ``action`` (default: the rig's own) at every integer frame of
    the action, (f, n), and the frames."""
    key = obj.data.shape_keys
    action = action or actions.active_action(key)
    if action is None:
        raise ShapeSpaceError(f"{obj.name!r} has no shape-key animation; choose an action", "no_action")
    if not actions.shape_key_curves(obj, action):
        raise ShapeSpaceError(f"action {action.name!r} animates none of {obj.name!r}'s shape keys", "no_channels")
    first, last = actions.frame_range(action)
    frames = np.arange(np.ceil(first), np.floor(last) + 1)
    return actions.sample_shape_keys(obj, names, frames, action), frames


# ------------------------------------------------------------------ conversions (3.7.3, 3.4.6)
def _new_object(obj, suffix: str, rest):
    """A new mesh object with ``obj``'s topology and transform, vertices at ``rest`` (p, 3)."""
    new = bpy.data.objects.new(f"{obj.name}_{suffix}", obj.data.copy())   # UVs, materials kept
    for coll in obj.users_collection:
        coll.objects.link(new)
    new.matrix_world = obj.matrix_world
    if new.data.shape_keys is not None:
        new.shape_key_clear()
    write_float(new.data.vertices, "co", rest)
    new.data.update()
    return new


def _add_key(obj, name, positions, relative_to=None, lo=0.0, hi=1.0):
    kb = obj.shape_key_add(name=name, from_mix=False)
    write_float(kb.data, "co", positions)
    if relative_to is not None:
        kb.relative_key = obj.data.shape_keys.key_blocks[relative_to]
    kb.slider_min, kb.slider_max = float(lo), float(hi)
    return kb


def _convex_driver(key, names) -> None:
    """Drive the Neutral key with 1 − Σ w: a Sum driver of the sliders through a first-order Generator
    modifier (1 − s) — no Python expression at evaluation, and no expression length limit."""
    kb = key.key_blocks[NEUTRAL_KEY]
    kb.driver_remove("value")
    fc = kb.driver_add("value")
    drv = fc.driver
    drv.type = "SUM"
    for i, name in enumerate(names):
        var = drv.variables.new()
        var.name = f"w{i}"
        var.targets[0].id_type = "KEY"
        var.targets[0].id = key
        var.targets[0].data_path = f'key_blocks["{bpy.utils.escape_identifier(name)}"].value'
    gen = fc.modifiers[0] if len(fc.modifiers) else fc.modifiers.new("GENERATOR")
    gen.mode, gen.poly_order = "POLYNOMIAL", 1
    gen.use_additive = False
    gen.coefficients = (1.0, -1.0)


def to_whole_face_object(obj, convex: bool = True):
    """A new object in whole-face form (3.7.3): every key holds a whole face ``b_k`` relative to a
    zero reference, plus a ``Neutral`` key ``b0``; the face is ``Σ_k c_k b_k`` over all keys.

    With ``convex`` the Neutral weight is driven as ``1 − Σ w`` so the same slider values give exactly
    the original rig's face (while Σw ≤ 11: Blender limits a slider to ±10); without it all whole-face
    weights are free (Σc ≠ 1 scales the head).
    """
    model = linear_model(obj)
    targets, neutral = fs.to_whole_face(model)
    new = _new_object(obj, "wholeface", np.zeros_like(neutral))
    new.shape_key_add(name=ZERO_KEY, from_mix=False)
    _add_key(new, NEUTRAL_KEY, neutral, ZERO_KEY, -10.0, 10.0)
    for k, name in enumerate(model.names):
        _add_key(new, name, targets[k], ZERO_KEY, model.slider_min[k], model.slider_max[k])
    key = new.data.shape_keys
    key[REPRESENTATION_PROP] = json.dumps({"form": "whole_face", "source": obj.name, "convex": bool(convex)})
    if convex:
        _convex_driver(key, model.names)
    else:
        key.key_blocks[NEUTRAL_KEY].value = 1.0
    return new


def to_delta_object(obj):
    """Back from a whole-face object to an ordinary (delta) rig: the Neutral key becomes the basis."""
    key = obj.data.shape_keys
    meta = json.loads(key.get(REPRESENTATION_PROP, "{}")) if key is not None else {}
    if meta.get("form") != "whole_face":
        raise ShapeSpaceError(f"{obj.name!r} is not a whole-face rig made by ShapeSpace", "not_whole_face")
    from .arrays import read_float
    blocks = [kb for kb in key.key_blocks if kb.name not in (ZERO_KEY, NEUTRAL_KEY)]
    neutral = read_float(key.key_blocks[NEUTRAL_KEY].data, "co", 3).astype(np.float64)
    targets = np.stack([read_float(kb.data, "co", 3).astype(np.float64) for kb in blocks])
    model = fs.from_whole_face(neutral, targets, [kb.name for kb in blocks],
                               [kb.slider_min for kb in blocks], [kb.slider_max for kb in blocks])
    new = _new_object(obj, "delta", model.neutral)
    new.shape_key_add(name="Basis", from_mix=False)
    for k, name in enumerate(model.names):
        _add_key(new, name, model.neutral + model.deltas[k], None, model.slider_min[k], model.slider_max[k])
    return new


def to_pca_object(obj, action=None, tol: float = None):
    """A new object whose sliders are PCA coefficients (3.4.6, 3.7.5).

    Without ``action``: an exact orthonormal basis of the rig's target span (mean = neutral), so every
    face of the rig is reachable.  With ``action``: the PCA of that animation's frames, with the fewest
    components whose max vertex error stays within ``tol`` (default 1e-3 of the head size).  The
    action is converted too (``c = A w + a`` by the precomputed affine map) into a new action on the
    new object.  Each key is one unit of its component's standard deviation / singular value.
    """
    model = linear_model(obj)
    if action is None:
        basis = fs.pca_from_model(model)
    else:
        W, frames = animation_weights(obj, model.names, action)
        tol = tol if tol is not None else 1e-3 * model.scale
        report = fs.compression_report(model, W, tol)
        if report.value is None:
            raise ShapeSpaceError(report.message, "tolerance_not_met")
        full = fs.animation_pca(model, W)                      # never forms the frames × 3p matrix
        m = max(int(report.value), 1)
        basis = fs.PCABasis(full.mean, full.components[:, :m], full.variances[:m])
    unit = np.sqrt(np.maximum(basis.variances, 1e-300))
    A, a = fs.blendshape_to_pca_maps(model, basis)
    new = _new_object(obj, "pca", basis.mean.reshape(-1, 3))
    new.shape_key_add(name="Mean", from_mix=False)
    names = [f"PC{i + 1:02d}" for i in range(basis.n_components)]
    for i, name in enumerate(names):
        _add_key(new, name, (basis.mean + unit[i] * basis.components[:, i]).reshape(-1, 3), None, -10.0, 10.0)
    key = new.data.shape_keys
    key[REPRESENTATION_PROP] = json.dumps({"form": "pca", "source": obj.name, "sliders": model.names,
                                           "A": (A / unit[:, None]).tolist(), "a": (a / unit).tolist()})
    if action is not None:
        C = (W @ A.T + a) / unit
        actions.key_shape_values(new, names, frames, C, f"{action.name}_pca")
    return new


def to_pca_object_relative(obj, from_animation: bool, tolerance: float):
    """:func:`to_pca_object` with the tolerance as a fraction of the head size and the rig's own action."""
    if not from_animation:
        return to_pca_object(obj)
    action = actions.active_action(obj.data.shape_keys)
    if action is None:
        raise ShapeSpaceError(f"{obj.name!r} has no shape-key animation to take components from", "no_action")
    return to_pca_object(obj, action, tolerance * linear_model(obj).scale)


def make_convex(obj) -> dict:
    """Convex slider mode (3.7.3): move the current slider values to the nearest ones whose whole-face
    weights are a convex combination — each within its range and [0, 1], and Σw ≤ 1 so the neutral's
    weight 1 − Σw stays ≥ 0.  Returns the sum before and after and how far the sliders moved."""
    model = linear_model(obj)
    w = shapekeys.read_slider_values(obj, model.names)
    lo = np.clip(model.slider_min, 0.0, 1.0)
    hi = np.clip(model.slider_max, 0.0, 1.0)
    x = fs.project_convex(w, lo, np.maximum(hi, lo))
    shapekeys.write_slider_values(obj, model.names, x)
    return {"sum_before": float(w.sum()), "sum_after": float(x.sum()), "moved": float(np.linalg.norm(x - w))}


# ------------------------------------------------------------------ reports and diagnostics (3.7)
def _store(obj, prop: str, data: dict) -> None:
    obj.data.shape_keys[prop] = json.dumps(data)


def stored(obj, prop: str) -> dict:
    key = obj.data.shape_keys if obj is not None and obj.type == "MESH" else None
    return json.loads(key.get(prop, "{}")) if key is not None else {}


def compression(obj, action, tol: float) -> dict:
    """How many PCA components keep an animation's max vertex error within ``tol`` (3.7.8)."""
    model = linear_model(obj)
    W, frames = animation_weights(obj, model.names, action)
    res = fs.compression_report(model, W, tol)
    d = res.diagnostics
    out = {"components": res.value, "targets": model.n_targets, "frames": int(frames.size), "tol": float(tol),
           "ratio": d["compression_ratio"], "animation_rank": d["animation_rank"], "rig_rank": d["rig_rank"],
           "message": res.message}
    data = stored(obj, ANALYSIS_PROP)
    data["compression"] = out
    _store(obj, ANALYSIS_PROP, data)
    if res.value is None:
        raise ShapeSpaceError(res.message, "tolerance_not_met")
    return out


def analyse(obj, action=None, png_path: str = None, threshold: float = 0.95) -> dict:
    """Coherence image (PNG + image datablock), near-duplicate pairs, empty targets and, with an
    animation, the sparsity of its blendshape weights vs PCA coefficients (3.7.1, 3.7.6, Figs 3.12–3.15)."""
    model = linear_model(obj)
    C = fs.coherence_matrix(model)
    image = fs.coherence_image(C)
    name = f"ShapeSpace Coherence {obj.name}"
    img = bpy.data.images.get(name)
    if img is not None and tuple(img.size) != (image.shape[1], image.shape[0]):
        bpy.data.images.remove(img)
        img = None
    img = img or bpy.data.images.new(name, image.shape[1], image.shape[0], alpha=True)
    img.pixels.foreach_set((image[::-1].astype(np.float32) / 255.0).ravel())   # Blender's rows go up
    if png_path:
        img.filepath_raw = png_path
        img.file_format = "PNG"
        img.save()
    else:
        img.pack()
    out = {"targets": model.n_targets, "mutual_coherence": float(fs.mutual_coherence(model)),
           "similar_pairs": [[a, b, float(c)] for a, b, c in fs.similar_pairs(model, threshold)],
           "empty_targets": fs.empty_targets(model), "image": img.name, "png": png_path or ""}
    key_action = action or actions.active_action(obj.data.shape_keys)
    if key_action is not None and actions.shape_key_curves(obj, key_action):
        W, _ = animation_weights(obj, model.names, key_action)
        sp = fs.sparsity_comparison(model, W)
        out["sparsity"] = {form: {k: float(v) for k, v in vals.items() if np.isscalar(v)}
                           for form, vals in sp.value.items()}
        out["sparsity_message"] = sp.message
    data = stored(obj, ANALYSIS_PROP)
    data.update({"coherence": out})
    _store(obj, ANALYSIS_PROP, data)
    return out


# ------------------------------------------------------------------ the face prior (3.7.9, ch. 6)
def learn_prior(obj, action=None) -> dict:
    """Fit the face-space Gaussian to an animation and store it on the rig (names, mean, eigenbasis)."""
    model = linear_model(obj)
    W, frames = animation_weights(obj, model.names, action)
    g = facestats.fit_face_gaussian(W)
    data = {"names": model.names, "mean": g.mean.tolist(), "eigvecs": g.eigvecs.tolist(),
            "eigvals": g.eigvals.tolist(), "dimension": g.dimension, "ridge": g.ridge,
            "regularised": g.regularised, "message": g.message, "frames": int(frames.size)}
    _store(obj, PRIOR_PROP, data)
    return {"frames": int(frames.size), "dimension": g.dimension, "regularised": g.regularised,
            "message": g.message}


def prior(obj):
    """The stored face Gaussian and its slider names, or ``(None, None)``."""
    data = stored(obj, PRIOR_PROP)
    if not data:
        return None, None
    g = facestats.FaceGaussian(np.array(data["mean"]), np.array(data["eigvecs"]), np.array(data["eigvals"]),
                               float(data["dimension"]), float(data["ridge"]), bool(data["regularised"]),
                               data["message"])
    return g, data["names"]


def _prior_or_error(obj):
    g, names = prior(obj)
    if g is None:
        raise ShapeSpaceError(f"{obj.name!r} has no face prior yet: learn one from an animation first",
                              "no_prior")
    missing = [n for n in names if n not in obj.data.shape_keys.key_blocks]
    if missing:
        raise ShapeSpaceError(f"the face prior was learnt with shape keys that are gone: {', '.join(missing)}",
                              "stale_prior")
    return g, names


def meter(obj) -> dict:
    """Where the current expression lies: face norm, the high-probability shell and the χ² percentile."""
    g, names = _prior_or_error(obj)
    w = shapekeys.read_slider_values(obj, names)
    res = g.plausibility(w[None])
    return {"norm": float(res.diagnostics["norm"][0]), "shell_radius": g.shell_radius,
            "percentile": float(res.diagnostics["percentile"][0]), "status": str(res.value[0])}


def implausible_frames(obj, action=None, alpha: float = 0.01) -> list:
    """``[(frame, reason)]`` of an animation's frames outside the prior's typical shell."""
    g, names = _prior_or_error(obj)
    W, frames = animation_weights(obj, names, action)
    idx, reasons = g.implausible_frames(W, alpha)
    return [(int(frames[i]), r) for i, r in zip(idx, reasons)]


def fill_between(obj, frame_a: int, frame_b: int, mode: str = "SHELL") -> int:
    """Key every frame strictly between ``frame_a`` and ``frame_b`` with expressions interpolated
    around the prior's hyperellipsoid (``SHELL``, norm-preserving, 6.5) or linearly (``LINEAR``)."""
    if mode not in ("SHELL", "LINEAR"):
        raise ShapeSpaceError(f"mode must be SHELL or LINEAR, got {mode!r}", "mode")
    if frame_b - frame_a < 2:
        raise ShapeSpaceError(f"frames {frame_a} and {frame_b} have nothing in between", "range")
    g, names = _prior_or_error(obj)
    key = obj.data.shape_keys
    action = actions.active_action(key)
    if action is None:
        raise ShapeSpaceError(f"{obj.name!r} has no shape-key animation to fill", "no_action")
    ends = actions.sample_shape_keys(obj, names, [frame_a, frame_b], action)
    inner = np.arange(frame_a + 1, frame_b)
    t = (inner - frame_a) / float(frame_b - frame_a)
    W = (facestats.shell_interpolate(g, ends[0], ends[1], t) if mode == "SHELL"
         else facestats.linear_interpolate(ends[0], ends[1], t))
    for j, name in enumerate(names):
        fc = actions.ensure_fcurve(key, actions.shape_key_path(name))
        actions.replace_keys_between(fc, frame_a + 1, frame_b - 1, inner, W[:, j])
    return int(inner.size)


def bracketing_keys(obj, frame: float):
    """The keyed frames just before and after ``frame`` over the rig's shape-key curves."""
    curves = actions.shape_key_curves(obj)
    keyed = np.unique(np.concatenate([actions.read_curve(fc)[0] for fc in curves.values()])) if curves \
        else np.zeros(0)
    before, after = keyed[keyed < frame], keyed[keyed > frame]
    if not before.size or not after.size:
        raise ShapeSpaceError(f"frame {frame:g} is not between two keys", "no_keys")
    return int(round(before[-1])), int(round(after[0]))


# ------------------------------------------------------------------ inpainting (9.3)
def _curve_owner(obj):
    """(ID, action) whose F-Curves animate ``obj``: its shape keys' when it has shape-key animation."""
    key = obj.data.shape_keys if obj.type == "MESH" else None
    if key is not None and actions.active_action(key) is not None:
        return key, actions.active_action(key)
    act = actions.active_action(obj)
    if act is None:
        raise ShapeSpaceError(f"{obj.name!r} has no animation", "no_action")
    return obj, act


def inpaint_gap(obj, data_path: str, index: int, start: int, end: int, use_other_channels: bool = True) -> dict:
    """Fill frames ``start … end`` of one F-Curve from the covariance of the rest of the animation
    (9.3), keying every frame of the gap; the known samples outside stay exactly as they were.

    With ``use_other_channels`` the other curves of the action whose motion correlates with the target's
    condition the fill too (superresolution: a knee from the hips), as many as the animation's length
    can support (:func:`core.facespace.stats.context_channels`)."""
    owner, action = _curve_owner(obj)
    curves = actions.fcurves(action, owner)
    target = next((fc for fc in curves if fc.data_path == data_path and fc.array_index == index), None)
    if target is None:
        raise ShapeSpaceError(f"{action.name!r} has no curve {data_path}[{index}]", "missing_curve")
    first, last = actions.frame_range(action)
    frames = np.arange(np.ceil(first), np.floor(last) + 1)
    if not (frames[0] <= start <= end <= frames[-1]):
        raise ShapeSpaceError(f"the gap {start}–{end} is outside the animation's frames "
                              f"{frames[0]:g}–{frames[-1]:g}", "range")
    others = [fc for fc in curves if use_other_channels
              and (fc.data_path, fc.array_index) != (target.data_path, target.array_index)]
    chans = [target] + others
    X = np.column_stack([actions.sample_curve(fc, frames) for fc in chans])
    gap_frames = (frames >= start) & (frames <= end)
    chosen = facestats.context_channels(X, 0, ~gap_frames, int(gap_frames.sum()))   # what the data supports
    X, chans = X[:, chosen], [chans[i] for i in chosen]
    known = np.ones(X.shape, bool)
    known[gap_frames, 0] = False
    res = facestats.inpaint_curve(X, known)
    filled = np.asarray(res.value)[:, 0]
    actions.replace_keys_between(target, start, end, frames[gap_frames], filled[gap_frames])
    return {"frames": int(gap_frames.sum()), "channels": len(chans), "method": res.diagnostics.get("method", ""),
            "message": res.message}


# ------------------------------------------------------------------ pose-space confidence (9.1–9.2)
CONFIDENCE_ATTRIBUTE = "ShapeSpace Confidence"


def confidence_model(deformer):
    """The Gaussian-process model of a trained pose-space deformer: its examples' poses, a Gaussian
    kernel of the deformer's width (prior variance 1)."""
    return gpconf.GPConfidence.fit(deformer.poses, "gaussian", float(deformer.epsilon))


def confidence(obj, heat_map: bool = False) -> dict:
    """Gaussian-process variance of the pose-space interpolant at the current pose (0 at an example,
    1 far from all), and optionally a per-vertex heat map of the predictive standard deviation
    (a colour attribute) showing where a new example would matter."""
    from . import posespace
    deformer, names = posespace.trained_deformer(obj)
    conf = confidence_model(deformer)
    pose = posespace.read_pose(obj)
    out = {"variance": float(conf.variance(pose)), "examples": len(names)}
    if heat_map:
        sd = gpconf.vertex_uncertainty(conf, pose, deformer.correctives)
        top = float(sd.max()) or 1.0
        t = np.clip(sd / top, 0.0, 1.0)
        rgba = np.column_stack([t, 0.2 * (1 - t), 1.0 - t, np.ones_like(t)])
        me = obj.data
        attr = me.color_attributes.get(CONFIDENCE_ATTRIBUTE)
        if attr is None or attr.domain != "POINT" or attr.data_type != "FLOAT_COLOR":
            if attr is not None:
                me.color_attributes.remove(attr)
            attr = me.color_attributes.new(CONFIDENCE_ATTRIBUTE, "FLOAT_COLOR", "POINT")
        write_float(attr.data, "color", rgba)
        me.color_attributes.active_color = attr
        out["max_sd"] = float(sd.max())
        out["attribute"] = CONFIDENCE_ATTRIBUTE
    return out


def default_png_path(obj) -> str:
    """Where the coherence PNG goes by default: next to the saved .blend, else the temp folder."""
    folder = os.path.dirname(bpy.data.filepath) if bpy.data.filepath else bpy.app.tempdir
    return os.path.join(folder, f"{bpy.path.clean_name(obj.name)}_coherence.png")
