"""Face-space tools in Blender (thesis 3.7, ch. 6, 9.3): rig conversions, diagnostics, the face prior,
shell in-betweens and curve inpainting.

Blender I/O and orchestration only: this module reads Blender data through the other bridge modules, hands
arrays to :mod:`core.facespace`, and writes *new* keys, objects, images or actions — the user's shape keys are
only changed by the verbs that say so (making the sliders convex, filling frames, inpainting a gap).  The JSON
blobs kept on the rig's Key datablock (:data:`REPRESENTATION_SCHEMA`, :data:`PRIOR_SCHEMA`,
:data:`ANALYSIS_SCHEMA`) are written and read through :mod:`bridge.storage`.
"""
from __future__ import annotations

import bpy
import numpy as np

from ..core import facespace as fs
from ..core import validate
from ..core.errors import ErrorCode
from ..core.result import ShapeSpaceError, to_jsonable
from ..core.schema import Schema
from . import actions, shapekeys, storage
from .arrays import read_float, write_float

REPRESENTATION_PROP = "shapespace_representation"
PRIOR_PROP = "shapespace_face_prior"
ANALYSIS_PROP = "shapespace_analysis"
NEUTRAL_KEY = "Neutral"
ZERO_KEY = "Zero"
#: Forms :func:`convert_rig` makes.
FORMS = ("WHOLE_FACE", "DELTA", "PCA")

#: What a converted copy is (Key custom property :data:`REPRESENTATION_PROP`): ``form`` "whole_face" (with
#: ``convex``) or "pca" (with the source ``sliders`` and the slider map ``A`` (m, n), ``a`` (m,)).
REPRESENTATION_SCHEMA = Schema("face-space representation", version=1,
                               fields={"form": "string", "source": "string"},
                               optional={"convex": "bool", "sliders": "list", "A": "list", "a": "list"})
#: The learnt face Gaussian (Key custom property :data:`PRIOR_PROP`), see :class:`core.facespace.FaceGaussian`.
PRIOR_SCHEMA = Schema("face prior", version=1,
                      fields={"names": "list", "mean": "list", "eigvecs": "list", "eigvals": "list",
                              "dimension": "number", "ridge": "number", "regularised": "bool", "message": "string"},
                      optional={"frames": "int"})
#: The last compression report and rig analysis (Key custom property :data:`ANALYSIS_PROP`), for the panel.
ANALYSIS_SCHEMA = Schema("face-space analysis", version=1,
                         optional={"compression": "object", "coherence": "object"})
_SCHEMAS = {REPRESENTATION_PROP: REPRESENTATION_SCHEMA, PRIOR_PROP: PRIOR_SCHEMA, ANALYSIS_PROP: ANALYSIS_SCHEMA}


def blob_schemas() -> dict:
    """The face-space blobs on a Key: property name → schema (for :func:`bridge.storage.upgrade_file`)."""
    return dict(_SCHEMAS)


# ------------------------------------------------------------------ shared readers
def linear_model(obj):
    """The rig as a :class:`BlendshapeModel`, refusing in-betweens and combinations (correctives are
    not faces: representations and statistics are about the primary sliders)."""
    model = shapekeys.read_blendshape_model(obj)
    if not model.is_linear:
        raise ShapeSpaceError("the rig has in-between or combination shapes: face-space tools work on its "
                              "primary sliders only; use a copy without them", ErrorCode.NONLINEAR)
    if model.n_targets == 0:
        raise ShapeSpaceError(f"{obj.name!r} has no shape keys besides its reference key", ErrorCode.NO_TARGETS)
    return model


def _integer_frames(action) -> np.ndarray:
    """Every whole frame of ``action``'s frame range."""
    first, last = actions.frame_range(action)
    return np.arange(np.ceil(first), np.floor(last) + 1)


def animation_weights(obj, names, action=None):
    """Values of the shape keys ``names`` in ``action`` (default: the rig's own) at every integer frame of
    the action, (f, n), and the frames."""
    key = obj.data.shape_keys
    action = action or actions.active_action(key)
    if action is None:
        raise ShapeSpaceError(f"{obj.name!r} has no shape-key animation; choose an action", ErrorCode.NO_ACTION)
    if not actions.shape_key_curves(obj, action):
        raise ShapeSpaceError(f"action {action.name!r} animates none of {obj.name!r}'s shape keys",
                              ErrorCode.NO_CHANNELS)
    frames = _integer_frames(action)
    return actions.sample_shape_keys(obj, names, frames, action), frames


def stored(obj, prop: str) -> dict:
    """The blob ``prop`` (one of the ``*_PROP`` keys) on ``obj``'s shape keys, checked and migrated; an empty
    blob (only ``schema_version``) when absent or when ``obj`` is not a mesh."""
    key = obj.data.shape_keys if obj is not None and obj.type == "MESH" else None
    return storage.read_id_blob(key, prop, _SCHEMAS[prop])


def _store(obj, prop: str, data: dict) -> None:
    """Write the blob ``prop`` on ``obj``'s shape keys (NaN and infinities become ``null``)."""
    storage.write_id_blob(obj.data.shape_keys, prop, _SCHEMAS[prop], to_jsonable(data))


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
    storage.write_id_blob(key, REPRESENTATION_PROP, REPRESENTATION_SCHEMA,
                          {"form": "whole_face", "source": obj.name, "convex": bool(convex)})
    if convex:
        _convex_driver(key, model.names)
    else:
        key.key_blocks[NEUTRAL_KEY].value = 1.0
    return new


def to_delta_object(obj):
    """Back from a whole-face object to an ordinary (delta) rig: the Neutral key becomes the basis."""
    key = obj.data.shape_keys
    meta = storage.read_id_blob(key, REPRESENTATION_PROP, REPRESENTATION_SCHEMA) if key is not None else {}
    if meta.get("form") != "whole_face":
        raise ShapeSpaceError(f"{obj.name!r} is not a whole-face rig made by ShapeSpace", ErrorCode.NOT_WHOLE_FACE)
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
        res = fs.compressed_animation_pca(model, W, tol if tol is not None else 1e-3 * model.scale)
        if res.value is None:
            raise ShapeSpaceError(res.message, ErrorCode.TOLERANCE_NOT_MET)
        basis = res.value
    sliders = fs.pca_sliders(model, basis)
    new = _new_object(obj, "pca", sliders.rest)
    new.shape_key_add(name="Mean", from_mix=False)
    names = [f"PC{i + 1:02d}" for i in range(basis.n_components)]
    for name, positions in zip(names, sliders.keys):
        _add_key(new, name, positions, None, -10.0, 10.0)
    storage.write_id_blob(new.data.shape_keys, REPRESENTATION_PROP, REPRESENTATION_SCHEMA,
                          {"form": "pca", "source": obj.name, "sliders": model.names,
                           "A": sliders.A.tolist(), "a": sliders.a.tolist()})
    if action is not None:
        actions.key_shape_values(new, names, frames, sliders.slider_values(W), f"{action.name}_pca")
    return new


def to_pca_object_relative(obj, from_animation: bool, tolerance: float):
    """:func:`to_pca_object` with the tolerance as a fraction of the head size and the rig's own action."""
    if not from_animation:
        return to_pca_object(obj)
    action = actions.active_action(obj.data.shape_keys)
    if action is None:
        raise ShapeSpaceError(f"{obj.name!r} has no shape-key animation to take components from",
                              ErrorCode.NO_ACTION)
    return to_pca_object(obj, action, tolerance * linear_model(obj).scale)


def convert_rig(obj, form: str, convex: bool = True, from_animation: bool = False, tolerance: float = 1e-3):
    """A converted copy of the rig in ``form`` (one of :data:`FORMS`): :func:`to_whole_face_object`,
    :func:`to_delta_object` or :func:`to_pca_object_relative`."""
    validate.choice(form, "form", FORMS, ErrorCode.MODE)
    if form == "WHOLE_FACE":
        return to_whole_face_object(obj, convex)
    if form == "DELTA":
        return to_delta_object(obj)
    return to_pca_object_relative(obj, from_animation, tolerance)


def make_convex(obj) -> dict:
    """Convex slider mode (3.7.3): move the current slider values to the nearest ones whose whole-face
    weights are a convex combination — each within its range and [0, 1], and Σw ≤ 1 so the neutral's
    weight 1 − Σw stays ≥ 0.  Returns the sum before and after and how far the sliders moved."""
    model = linear_model(obj)
    w = shapekeys.read_slider_values(obj, model.names)
    res = fs.convex_slider_values(w, model.slider_min, model.slider_max)
    shapekeys.write_slider_values(obj, model.names, res.value)
    return {k: res.diagnostics[k] for k in ("sum_before", "sum_after", "moved")}


# ------------------------------------------------------------------ reports and diagnostics (3.7)
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
        raise ShapeSpaceError(res.message, ErrorCode.TOLERANCE_NOT_MET)
    return out


def compression_relative(obj, tolerance: float) -> dict:
    """:func:`compression` of the rig's own action with ``tolerance`` a fraction of the head size."""
    return compression(obj, None, tolerance * linear_model(obj).scale)


def _coherence_image(name: str, image: np.ndarray, png_path: str = None):
    """The image datablock ``name`` holding ``image`` (rows top-down, RGBA uint8), saved as a PNG or packed."""
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
    return img


def analyse(obj, action=None, png_path: str = None, threshold: float = 0.95) -> dict:
    """Coherence image (PNG + image datablock), near-duplicate pairs, empty targets and, with an
    animation, the sparsity of its blendshape weights vs PCA coefficients (3.7.1, 3.7.6, Figs 3.12–3.15)."""
    model = linear_model(obj)
    img = _coherence_image(f"ShapeSpace Coherence {obj.name}", fs.coherence_image(fs.coherence_matrix(model)),
                           png_path)
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
    data["coherence"] = out
    _store(obj, ANALYSIS_PROP, data)
    return out


# ------------------------------------------------------------------ the face prior (3.7.9, ch. 6)
def learn_prior(obj, action=None) -> dict:
    """Fit the face-space Gaussian to an animation and store it on the rig (names, mean, eigenbasis)."""
    model = linear_model(obj)
    W, frames = animation_weights(obj, model.names, action)
    g = fs.fit_face_gaussian(W)
    data = {"names": model.names, "mean": g.mean.tolist(), "eigvecs": g.eigvecs.tolist(),
            "eigvals": g.eigvals.tolist(), "dimension": g.dimension, "ridge": g.ridge,
            "regularised": g.regularised, "message": g.message, "frames": int(frames.size)}
    _store(obj, PRIOR_PROP, data)
    return {"frames": int(frames.size), "dimension": g.dimension, "regularised": g.regularised,
            "message": g.message}


def has_prior(obj) -> bool:
    """Whether ``obj``'s shape keys carry a learnt face prior."""
    key = obj.data.shape_keys if obj is not None and obj.type == "MESH" else None
    return key is not None and PRIOR_PROP in key


def prior(obj):
    """The stored face Gaussian and its slider names, or ``(None, None)``."""
    data = stored(obj, PRIOR_PROP)
    if "mean" not in data:
        return None, None
    g = fs.FaceGaussian(np.array(data["mean"]), np.array(data["eigvecs"]), np.array(data["eigvals"]),
                        float(data["dimension"]), float(data["ridge"]), bool(data["regularised"]), data["message"])
    return g, data["names"]


def _prior_or_error(obj):
    g, names = prior(obj)
    if g is None:
        raise ShapeSpaceError(f"{obj.name!r} has no face prior yet: learn one from an animation first",
                              ErrorCode.NO_PRIOR)
    missing = [n for n in names if n not in obj.data.shape_keys.key_blocks]
    if missing:
        raise ShapeSpaceError(f"the face prior was learnt with shape keys that are gone: {', '.join(missing)}",
                              ErrorCode.STALE_PRIOR)
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


def flag_implausible_frames(obj, action=None, alpha: float = 0.01) -> list:
    """:func:`implausible_frames`, also listed in ``obj.shapespace_face.implausible`` for the panel."""
    found = implausible_frames(obj, action, alpha)
    items = obj.shapespace_face.implausible
    items.clear()
    for frame, reason in found:
        item = items.add()
        item.frame, item.reason = frame, reason
    return found


def fill_between(obj, frame_a: int, frame_b: int, mode: str = "SHELL") -> int:
    """Key every frame strictly between ``frame_a`` and ``frame_b`` with expressions interpolated
    around the prior's hyperellipsoid (``SHELL``, norm-preserving, 6.5) or linearly (``LINEAR``)."""
    validate.choice(mode, "mode", fs.INTERPOLATIONS, ErrorCode.MODE)
    inner, t = fs.inbetween_times(frame_a, frame_b)
    g, names = _prior_or_error(obj)
    key = obj.data.shape_keys
    action = actions.active_action(key)
    if action is None:
        raise ShapeSpaceError(f"{obj.name!r} has no shape-key animation to fill", ErrorCode.NO_ACTION)
    ends = actions.sample_shape_keys(obj, names, [frame_a, frame_b], action)
    W = fs.interpolate(g, ends[0], ends[1], t, mode)
    for j, name in enumerate(names):
        fc = actions.ensure_fcurve(key, actions.shape_key_path(name))
        actions.replace_keys_between(fc, frame_a + 1, frame_b - 1, inner, W[:, j])
    return int(inner.size)


def keyed_frames(obj) -> np.ndarray:
    """Every keyed frame (k,) of the rig's shape-key curves (repeats included)."""
    curves = actions.shape_key_curves(obj)
    return np.concatenate([actions.read_curve(fc)[0] for fc in curves.values()]) if curves else np.zeros(0)


def fill_around(obj, frame: float, frame_start: int = -1, frame_end: int = -1, mode: str = "SHELL") -> dict:
    """:func:`fill_between` from ``frame_start`` to ``frame_end``; a negative one means the key just
    before / after ``frame``.  Returns the frames filled and the two frames used."""
    keyed = keyed_frames(obj) if frame_start < 0 or frame_end < 0 else np.zeros(0)
    a, b = fs.fill_range(keyed, frame, frame_start, frame_end)
    return {"frames": fill_between(obj, a, b, mode), "start": a, "end": b}


def set_frame(scene, frame: int) -> None:
    """Make ``frame`` the scene's current frame."""
    scene.frame_set(frame)


# ------------------------------------------------------------------ inpainting (9.3)
def _curve_owner(obj):
    """(ID, action) whose F-Curves animate ``obj``: its shape keys' when it has shape-key animation."""
    key = obj.data.shape_keys if obj.type == "MESH" else None
    if key is not None and actions.active_action(key) is not None:
        return key, actions.active_action(key)
    act = actions.active_action(obj)
    if act is None:
        raise ShapeSpaceError(f"{obj.name!r} has no animation", ErrorCode.NO_ACTION)
    return obj, act


def inpaint_gap(obj, data_path: str, index: int, start: int, end: int, use_other_channels: bool = True) -> dict:
    """Fill frames ``start … end`` of one F-Curve from the covariance of the rest of the animation
    (9.3), keying every frame of the gap; the known samples outside stay exactly as they were.

    With ``use_other_channels`` the other curves of the action whose motion correlates with the target's
    condition the fill too (superresolution: a knee from the hips), as many as the animation's length
    can support (:func:`core.facespace.fill_gap`)."""
    owner, action = _curve_owner(obj)
    curves = actions.fcurves(action, owner)
    target = next((fc for fc in curves if fc.data_path == data_path and fc.array_index == index), None)
    if target is None:
        raise ShapeSpaceError(f"{action.name!r} has no curve {data_path}[{index}]", ErrorCode.MISSING_CURVE)
    frames = _integer_frames(action)
    gap = fs.gap_mask(frames, start, end)
    others = [fc for fc in curves if use_other_channels
              and (fc.data_path, fc.array_index) != (target.data_path, target.array_index)]
    X = np.column_stack([actions.sample_curve(fc, frames) for fc in [target] + others])
    res = fs.fill_gap(X, gap)
    actions.replace_keys_between(target, start, end, frames[gap], res.value[gap])
    return {"frames": int(gap.sum()), "channels": len(res.diagnostics["channels"]),
            "method": res.diagnostics.get("method", ""), "message": res.message}
