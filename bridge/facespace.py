"""Face-space tools in Blender (thesis 3.7, ch. 6, 9.3): rig conversions, diagnostics, the face prior,
shell in-betweens and curve inpainting.

Blender I/O and orchestration only: this module reads Blender data through the other bridge modules, hands
arrays to :mod:`core.facespace`, and writes *new* keys, objects, images or actions — the user's shape keys are
only changed by the verbs that say so (making the sliders convex, filling frames, inpainting a gap).  The JSON
blobs kept on the rig's Key datablock (:data:`REPRESENTATION_SCHEMA`, :data:`PRIOR_SCHEMA`,
:data:`ANALYSIS_SCHEMA`) are written and read through :mod:`bridge.storage`.
"""
from __future__ import annotations

import json
import os

import bpy
import numpy as np

from ..core import blobs
from ..core import facespace as fs
from ..core import validate
from ..core.errors import ErrorCode
from ..core.result import ShapeSpaceError, to_jsonable
from ..core import schema as _schema
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
#: Blender's hard limit of a shape key's value (``slider_min`` ≥ −10, ``slider_max`` ≤ 10): a driven value
#: beyond it is clamped.
SLIDER_LIMIT = 10.0
#: Longest animation (in frames) the face-space tools sample.
MAX_FRAMES = 1_000_000
_FLOAT32_MAX = float(np.finfo(np.float32).max)

#: What a converted copy is (Key custom property :data:`REPRESENTATION_PROP`): ``form`` "whole_face" (with
#: ``convex`` and ``neutral_keys``, the keys sharing the neutral's weight; absent in files of 0.1.0: one key
#: :data:`NEUTRAL_KEY`) or "pca" (with the source ``sliders`` and the slider map ``A`` (m, n), ``a`` (m,)).
REPRESENTATION_SCHEMA = blobs.REPRESENTATION.schema
#: The learnt face Gaussian (Key custom property :data:`PRIOR_PROP`), see :class:`core.facespace.FaceGaussian`.
PRIOR_SCHEMA = blobs.FACE_PRIOR.schema
#: The last compression report and rig analysis (Key custom property :data:`ANALYSIS_PROP`), for the panel.
ANALYSIS_SCHEMA = blobs.ANALYSIS.schema
_SCHEMAS = {REPRESENTATION_PROP: REPRESENTATION_SCHEMA, PRIOR_PROP: PRIOR_SCHEMA, ANALYSIS_PROP: ANALYSIS_SCHEMA}
#: The two reports inside :data:`ANALYSIS_SCHEMA` (what :func:`compression` and :func:`analyse` write).
COMPRESSION_SCHEMA = blobs.ANALYSIS.sections["compression"]
COHERENCE_SCHEMA = blobs.ANALYSIS.sections["coherence"]


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


def _tick(progress, fraction: float) -> None:
    """Report ``fraction`` (0 … 1) of the work done to ``progress`` (a callable, or None)."""
    if progress is not None:
        progress(fraction)


def _curve_name(fc) -> str:
    """How a message names an F-Curve: ``key_blocks["jawOpen"].value`` or ``location[1]``."""
    return fc.data_path if fc.data_path.startswith("key_blocks[") else f"{fc.data_path}[{fc.array_index}]"


def _refuse_non_finite_frames(action, fc, kx) -> None:
    """Refuse keys of ``fc`` on NaN or infinite frames ``kx`` (they corrupt the action's frame range)."""
    bad = ~np.isfinite(kx)
    if bad.any():
        raise ShapeSpaceError(f"action {action.name!r}: curve {_curve_name(fc)} has a keyframe at a non-finite "
                              f"frame ({kx[bad][0]}); fix or delete that key", ErrorCode.NON_FINITE)


def _refuse_non_finite_keys(action, curves, skip=None) -> None:
    """Refuse a curve with a keyframe on a NaN or infinite frame or with such a value, naming the action, the
    curve and the frame.  ``skip`` = (start, end): values of keys on those frames are not checked (they are
    being replaced).  Handles are judged by what the curve evaluates to (:func:`_refuse_non_finite_samples`)."""
    for fc in curves:
        kx, ky, _ = actions.read_curve(fc)
        _refuse_non_finite_frames(action, fc, kx)
        bad = ~np.isfinite(ky) | (np.abs(ky) >= _FLOAT32_MAX)    # Blender stores an infinite key as ±FLT_MAX
        if skip is not None:
            bad &= ~((kx >= skip[0]) & (kx <= skip[1]))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ShapeSpaceError(f"action {action.name!r}: curve {_curve_name(fc)} has a non-finite keyframe "
                                  f"(value {ky[i]:g}) at frame {kx[i]:g}; fix or delete that key", ErrorCode.NON_FINITE)


def _refuse_non_finite_samples(action, fc, frames, values, label: str = None) -> None:
    """Refuse samples ``values`` (f,) of ``fc`` (or, without a curve, of the value ``label``) that are not
    finite, naming the curve and the first such frame."""
    bad = ~np.isfinite(values)
    if bad.any():
        frame = frames[int(np.flatnonzero(bad)[0])]
        what = f"curve {_curve_name(fc)} of action {action.name!r}" if fc is not None else label
        raise ShapeSpaceError(f"{what} evaluates to {values[bad][0]} at frame {frame:g}: fix the curve (a damaged "
                              "key or handle near that frame, or a modifier)", ErrorCode.NON_FINITE)


def _integer_frames(action) -> np.ndarray:
    """Every whole frame of ``action``'s frame range (its keys checked to lie on finite frames)."""
    for fc in actions.action_fcurves(action):
        _refuse_non_finite_frames(action, fc, actions.read_curve(fc)[0])
    first, last = actions.frame_range(action)
    if not (np.isfinite(first) and np.isfinite(last)) or last - first > MAX_FRAMES:
        raise ShapeSpaceError(f"action {action.name!r} spans frames {first:g}–{last:g}: more than {MAX_FRAMES} "
                              "frames", ErrorCode.TOO_LARGE)
    return np.arange(np.ceil(first), np.floor(last) + 1)


def animation_weights(obj, names, action=None, min_frames: int = 1):
    """Values of the shape keys ``names`` in ``action`` (default: the rig's own) at every integer frame of
    the action, (f, n), and the frames.  Each value is clamped to its slider's range, as Blender applies it
    (a curve overshooting the range does not move the face further).  A NaN or infinite keyframe (or value)
    is refused, naming the curve and the frame, and so is an action of fewer than ``min_frames`` frames."""
    key = obj.data.shape_keys
    action = action or actions.active_action(key)
    if action is None:
        raise ShapeSpaceError(f"{obj.name!r} has no shape-key animation; choose an action", ErrorCode.NO_ACTION)
    curves = actions.shape_key_curves(obj, action)
    if not curves:
        raise ShapeSpaceError(f"action {action.name!r} animates none of {obj.name!r}'s shape keys",
                              ErrorCode.NO_CHANNELS)
    _refuse_non_finite_keys(action, [curves[n] for n in names if n in curves])
    frames = _integer_frames(action)
    if frames.size < min_frames:
        raise ShapeSpaceError(f"action {action.name!r} spans {frames.size} frame(s): this needs at least "
                              f"{min_frames}", ErrorCode.TOO_FEW)
    W = actions.sample_shape_keys(obj, names, frames, action)
    for j, name in enumerate(names):
        _refuse_non_finite_samples(action, curves.get(name), frames, W[:, j], f"shape key {name!r} of {obj.name!r}")
    blocks = key.key_blocks
    lo = np.array([blocks[n].slider_min for n in names], dtype=np.float64)
    hi = np.array([blocks[n].slider_max for n in names], dtype=np.float64)
    return np.clip(W, lo, hi), frames


def _damaged(id_block, prop: str, what: str) -> ShapeSpaceError:
    """The one-line error for a blob that reads as JSON but does not fit the rig (code ``corrupt_metadata``)."""
    return ShapeSpaceError(f"damaged ShapeSpace data in {storage.where(id_block, prop)}: {what}",
                           ErrorCode.CORRUPT_METADATA)


def stored(obj, prop: str) -> dict:
    """The blob ``prop`` (one of the ``*_PROP`` keys) on ``obj``'s shape keys, checked and migrated; an empty
    blob (only ``schema_version``) when absent or when ``obj`` is not a mesh."""
    key = obj.data.shape_keys if obj is not None and obj.type == "MESH" else None
    return storage.read_id_blob(key, prop, _SCHEMAS[prop])


def _store(obj, prop: str, data: dict) -> None:
    """Write the blob ``prop`` on ``obj``'s shape keys (NaN and infinities become ``null``)."""
    storage.write_id_blob(obj.data.shape_keys, prop, _SCHEMAS[prop], to_jsonable(data))


def _check_report(key, section: str, data: dict, schema: Schema) -> None:
    """Check one report of the analysis blob against ``schema`` (same messages as the blob itself)."""
    where = f"{storage.where(key, ANALYSIS_PROP)} ▸ {section}"
    _schema.loads(json.dumps(data), schema, where)


def _check_coherence_items(key, coh: dict) -> None:
    if not all(isinstance(n, str) for n in coh["empty_targets"]):
        raise _damaged(key, ANALYSIS_PROP, "coherence: every empty target must be a shape-key name")
    for pair in coh["similar_pairs"]:
        ok = isinstance(pair, list) and len(pair) == 3 and all(isinstance(v, str) for v in pair[:2]) \
            and isinstance(pair[2], (int, float)) and not isinstance(pair[2], bool)
        if not ok:
            raise _damaged(key, ANALYSIS_PROP, f"coherence: similar pair {pair!r:.60} must be [name, name, number]")
    sparsity = coh.get("sparsity")
    if sparsity:
        for form in ("blendshape", "pca"):
            entry = sparsity.get(form)
            value = entry.get("curve_small_fraction", "missing") if isinstance(entry, dict) else "missing"
            if value is not None and (not isinstance(value, (int, float)) or isinstance(value, bool)):
                raise _damaged(key, ANALYSIS_PROP, f"coherence: sparsity needs {form}.curve_small_fraction "
                                                   "(a number)")


def stored_analysis(obj) -> dict:
    """The analysis blob (:data:`ANALYSIS_PROP`) with its two reports checked field by field: what the panel
    may show and :func:`compression` / :func:`analyse` may extend."""
    data = stored(obj, ANALYSIS_PROP)
    key = obj.data.shape_keys
    if "compression" in data:
        _check_report(key, "compression", data["compression"], COMPRESSION_SCHEMA)
    if "coherence" in data:
        _check_report(key, "coherence", data["coherence"], COHERENCE_SCHEMA)
        _check_coherence_items(key, data["coherence"])
    return data


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


def _neutral_key_names(count: int) -> list:
    """Names of the ``count`` keys sharing the neutral's weight: ``Neutral``, ``Neutral 2``, …"""
    return [NEUTRAL_KEY] + [f"{NEUTRAL_KEY} {i}" for i in range(2, count + 1)]


def _convex_driver(key, neutral_name: str, names, share: float) -> None:
    """Drive the key ``neutral_name`` with ``share · (1 − Σ w)``: a Sum driver of the sliders through a
    first-order Generator modifier — no Python expression at evaluation, and no expression length limit."""
    kb = key.key_blocks[neutral_name]
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
    gen.coefficients = (share, -share)


def to_whole_face_object(obj, convex: bool = True, progress=None):
    """A new object in whole-face form (3.7.3): every key holds a whole face ``b_k`` relative to a
    zero reference, plus the neutral ``b0``; the face is ``Σ_k c_k b_k`` over all keys.

    With ``convex`` the neutral's weight is driven as ``c0 = 1 − Σ w`` so the same slider values give exactly
    the original rig's face.  Blender clamps a key's value to ±10, so ``b0`` is held by ``K`` identical keys
    (``Neutral``, ``Neutral 2``, …, each leading a run of the targets), each driven by ``c0 / K`` with ``K``
    from the sliders' ranges (:func:`core.facespace.neutral_key_count`): exact for every slider setting the
    ranges allow (to float32 rounding).  Without it
    the one Neutral weight is free (Σc ≠ 1 scales the head).  ``progress``: see :func:`to_pca_object`.
    """
    model = linear_model(obj)
    count = fs.neutral_key_count(model.slider_min, model.slider_max, SLIDER_LIMIT) if convex else 1
    neutral_names = _neutral_key_names(count)
    clash = [n for n in model.names if n in neutral_names or n == ZERO_KEY]
    if clash:
        raise ShapeSpaceError(f"shape key {clash[0]!r} of {obj.name!r} has a name the whole-face copy needs for "
                              "its own keys: rename it first", ErrorCode.RESERVED_NAME)
    targets, neutral = fs.to_whole_face(model)
    new = _new_object(obj, "wholeface", np.zeros_like(neutral))
    new.shape_key_add(name=ZERO_KEY, from_mix=False)
    # each Neutral share leads its own run of targets: Blender sums the keys in order in float32, and
    # interleaving keeps that running sum near one face instead of −Σw faces (3–6× less rounding)
    for name, run in zip(neutral_names, np.array_split(np.arange(model.n_targets), count)):
        _add_key(new, name, neutral, ZERO_KEY, -SLIDER_LIMIT, SLIDER_LIMIT)
        for k in run:
            _add_key(new, model.names[k], targets[k], ZERO_KEY, model.slider_min[k], model.slider_max[k])
            _tick(progress, 0.9 * (k + 1) / model.n_targets)
    key = new.data.shape_keys
    storage.write_id_blob(key, REPRESENTATION_PROP, REPRESENTATION_SCHEMA,
                          {"form": "whole_face", "source": obj.name, "convex": bool(convex),
                           "neutral_keys": neutral_names})
    if convex:
        for name in neutral_names:
            _convex_driver(key, name, model.names, 1.0 / count)
    else:
        key.key_blocks[NEUTRAL_KEY].value = 1.0
    _tick(progress, 1.0)
    return new


def _whole_face_layout(obj) -> tuple:
    """``(metadata, neutral key names)`` of a whole-face copy, checked against its keys."""
    key = obj.data.shape_keys
    meta = storage.read_id_blob(key, REPRESENTATION_PROP, REPRESENTATION_SCHEMA) if key is not None else {}
    if meta.get("form") != "whole_face":
        raise ShapeSpaceError(f"{obj.name!r} is not a whole-face rig made by ShapeSpace", ErrorCode.NOT_WHOLE_FACE)
    names = meta.get("neutral_keys", [NEUTRAL_KEY])
    if not names or not all(isinstance(n, str) for n in names):
        raise _damaged(key, REPRESENTATION_PROP, "neutral_keys must be a non-empty list of shape-key names")
    missing = [n for n in names if n not in key.key_blocks]
    if missing:
        raise ShapeSpaceError(f"the whole-face rig {obj.name!r} has lost its key {missing[0]!r} (it holds the "
                              "neutral face)", ErrorCode.MISSING_KEY)
    return meta, names


def whole_face_issue(obj):
    """Why the whole-face copy ``obj`` no longer matches its source for every slider setting, or None: its
    stored form is damaged, or its slider ranges were widened past what its Neutral keys can share."""
    key = obj.data.shape_keys if obj is not None and obj.type == "MESH" else None
    if key is None or REPRESENTATION_PROP not in key:
        return None
    try:
        meta, names = _whole_face_layout(obj)
        sliders = [kb for kb in key.key_blocks
                   if kb != key.reference_key and kb.name != ZERO_KEY and kb.name not in names]
        need = fs.neutral_key_count([kb.slider_min for kb in sliders], [kb.slider_max for kb in sliders],
                                    SLIDER_LIMIT)
    except ShapeSpaceError as exc:
        return None if exc.code == ErrorCode.NOT_WHOLE_FACE else str(exc)
    if meta.get("convex") and need > len(names):
        return (f"the slider ranges allow sums its {len(names)} Neutral key(s) cannot follow (Blender clamps "
                f"each to ±{SLIDER_LIMIT:g}): convert the rig again")
    return None


def to_delta_object(obj):
    """Back from a whole-face object to an ordinary (delta) rig: the Neutral key becomes the basis."""
    _, neutral_names = _whole_face_layout(obj)
    shapekeys.read_blendshape_model(obj)          # refuses NaN, empty or mismatched keys, naming them
    key = obj.data.shape_keys
    blocks = [kb for kb in key.key_blocks
              if kb != key.reference_key and kb.name != ZERO_KEY and kb.name not in neutral_names]
    if not blocks:
        raise ShapeSpaceError(f"the whole-face rig {obj.name!r} has no keys besides its neutral", ErrorCode.NO_TARGETS)
    neutral = read_float(key.key_blocks[neutral_names[0]].data, "co", 3).astype(np.float64)
    targets = np.stack([read_float(kb.data, "co", 3).astype(np.float64) for kb in blocks])
    model = fs.from_whole_face(neutral, targets, [kb.name for kb in blocks],
                               [kb.slider_min for kb in blocks], [kb.slider_max for kb in blocks])
    new = _new_object(obj, "delta", model.neutral)
    new.shape_key_add(name="Basis", from_mix=False)
    for k, name in enumerate(model.names):
        _add_key(new, name, model.neutral + model.deltas[k], None, model.slider_min[k], model.slider_max[k])
    return new


def to_pca_object(obj, action=None, tol: float = None, progress=None):
    """A new object whose sliders are PCA coefficients (3.4.6, 3.7.5).

    Without ``action``: an exact orthonormal basis of the rig's target span (mean = neutral), so every
    face of the rig is reachable.  With ``action``: the PCA of that animation's frames, with the fewest
    components whose max vertex error stays within ``tol`` (default 1e-3 of the head size).  The
    action is converted too (``c = A w + a`` by the precomputed affine map) into a new action on the
    new object.  Each key is one unit of its component's standard deviation / singular value (more where a
    frame would otherwise need a slider beyond Blender's ±10).
    ``progress`` (optional) is called with the fraction of the work done.
    """
    model = linear_model(obj)
    _tick(progress, 0.1)
    if action is None:
        basis = fs.pca_from_model(model)
    else:
        W, frames = animation_weights(obj, model.names, action, min_frames=2)
        _tick(progress, 0.2)
        res = fs.compressed_animation_pca(model, W, tol if tol is not None else 1e-3 * model.scale)
        if res.value is None:
            raise ShapeSpaceError(res.message, ErrorCode.TOLERANCE_NOT_MET)
        basis = res.value
    if basis.n_components == 0:
        what = f"the shape keys of {obj.name!r} move" if action is None else f"action {action.name!r} moves"
        raise ShapeSpaceError(f"{what} no vertex: a PCA copy would have no sliders", ErrorCode.EMPTY)
    _tick(progress, 0.6)
    sliders = fs.pca_sliders(model, basis, None if action is None else W, SLIDER_LIMIT)
    _tick(progress, 0.7)
    new = _new_object(obj, "pca", sliders.rest)
    new.shape_key_add(name="Mean", from_mix=False)
    names = [f"PC{i + 1:02d}" for i in range(basis.n_components)]
    for i, (name, positions) in enumerate(zip(names, sliders.keys)):
        _add_key(new, name, positions, None, -10.0, 10.0)
        _tick(progress, 0.7 + 0.25 * (i + 1) / len(names))
    storage.write_id_blob(new.data.shape_keys, REPRESENTATION_PROP, REPRESENTATION_SCHEMA,
                          {"form": "pca", "source": obj.name, "sliders": model.names,
                           "A": sliders.A.tolist(), "a": sliders.a.tolist()})
    if action is not None:
        actions.key_shape_values(new, names, frames, sliders.slider_values(W), f"{action.name}_pca")
    _tick(progress, 1.0)
    return new


def to_pca_object_relative(obj, from_animation: bool, tolerance: float, progress=None):
    """:func:`to_pca_object` with the tolerance as a fraction of the head size and the rig's own action."""
    if not from_animation:
        return to_pca_object(obj, progress=progress)
    action = actions.active_action(obj.data.shape_keys)
    if action is None:
        raise ShapeSpaceError(f"{obj.name!r} has no shape-key animation to take components from",
                              ErrorCode.NO_ACTION)
    return to_pca_object(obj, action, tolerance * linear_model(obj).scale, progress)


def convert_rig(obj, form: str, convex: bool = True, from_animation: bool = False, tolerance: float = 1e-3,
                progress=None):
    """A converted copy of the rig in ``form`` (one of :data:`FORMS`): :func:`to_whole_face_object`,
    :func:`to_delta_object` or :func:`to_pca_object_relative` (``progress``: see :func:`to_pca_object`)."""
    validate.choice(form, "form", FORMS, ErrorCode.MODE)
    if form == "WHOLE_FACE":
        return to_whole_face_object(obj, convex, progress)
    if form == "DELTA":
        return to_delta_object(obj)
    return to_pca_object_relative(obj, from_animation, tolerance, progress)


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
def compression(obj, action, tol: float, progress=None) -> dict:
    """How many PCA components keep an animation's max vertex error within ``tol`` (3.7.8).

    The report is stored for the panel (also when no number of components reaches ``tol``, which is then
    raised as an error).  ``progress`` (optional) is called with the fraction of the work done.
    """
    model = linear_model(obj)
    data = stored_analysis(obj)
    W, frames = animation_weights(obj, model.names, action, min_frames=2)
    _tick(progress, 0.2)
    res = fs.compression_report(model, W, tol)
    _tick(progress, 0.95)
    d = res.diagnostics
    out = {"components": res.value, "targets": model.n_targets, "frames": int(frames.size), "tol": float(tol),
           "ratio": d["compression_ratio"], "animation_rank": d["animation_rank"], "rig_rank": d["rig_rank"],
           "message": res.message}
    data["compression"] = out
    _store(obj, ANALYSIS_PROP, data)
    _tick(progress, 1.0)
    if res.value is None:
        raise ShapeSpaceError(res.message, ErrorCode.TOLERANCE_NOT_MET)
    return out


def compression_relative(obj, tolerance: float, progress=None) -> dict:
    """:func:`compression` of the rig's own action with ``tolerance`` a fraction of the head size."""
    return compression(obj, None, tolerance * linear_model(obj).scale, progress)


def _png_target(path: str) -> str:
    """The absolute path to write the coherence PNG to, refused when that would overwrite something else:
    a .blend file, a folder, a missing folder, a non-regular file or an existing file that is not a PNG."""
    path = os.path.normpath(os.path.abspath(path))
    blend = bpy.data.filepath and os.path.normpath(os.path.abspath(bpy.data.filepath))
    if path == blend or path.lower().endswith((".blend", ".blend1")):
        raise ShapeSpaceError(f"{path!r} is a .blend file: give a .png file path", ErrorCode.OVERWRITE)
    if os.path.isdir(path):
        raise ShapeSpaceError(f"{path!r} is a folder: give a .png file path", ErrorCode.NOT_A_FILE)
    if not os.path.isdir(os.path.dirname(path)):
        raise ShapeSpaceError(f"the folder of {path!r} does not exist", ErrorCode.UNWRITABLE)
    if os.path.lexists(path):
        if not os.path.isfile(path):
            raise ShapeSpaceError(f"{path!r} is not a regular file", ErrorCode.NOT_A_FILE)
        try:
            with open(path, "rb") as fh:
                head = fh.read(8)
        except OSError as exc:
            raise ShapeSpaceError(f"cannot read {path!r} ({exc.strerror})", ErrorCode.UNWRITABLE) from None
        if head != b"\x89PNG\r\n\x1a\n":
            raise ShapeSpaceError(f"{path!r} exists and is not a PNG image: choose another file",
                                  ErrorCode.OVERWRITE)
    return path


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
        try:
            img.save()
        except RuntimeError as exc:
            raise ShapeSpaceError(f"could not write {png_path!r}: {str(exc).strip().splitlines()[-1]}",
                                  ErrorCode.UNWRITABLE) from None
    else:
        img.pack()
    return img


def analyse(obj, action=None, png_path: str = None, threshold: float = 0.95, progress=None) -> dict:
    """Coherence image (PNG + image datablock), near-duplicate pairs, empty targets and, with an
    animation, the sparsity of its blendshape weights vs PCA coefficients (3.7.1, 3.7.6, Figs 3.12–3.15).

    Everything is read and computed before the image is made and the report stored.  ``progress``
    (optional) is called with the fraction of the work done.
    """
    png_path = _png_target(png_path) if png_path else None
    model = linear_model(obj)
    data = stored_analysis(obj)
    _tick(progress, 0.1)
    coherence = fs.coherence_matrix(model)
    out = {"targets": model.n_targets, "mutual_coherence": float(fs.mutual_coherence(model)),
           "similar_pairs": [[a, b, float(c)] for a, b, c in fs.similar_pairs(model, threshold)],
           "empty_targets": fs.empty_targets(model), "png": png_path or ""}
    _tick(progress, 0.4)
    key_action = action or actions.active_action(obj.data.shape_keys)
    W = animation_weights(obj, model.names, key_action)[0] \
        if key_action is not None and actions.shape_key_curves(obj, key_action) else np.zeros((0, 0))
    if W.shape[0] >= 2:                     # sparsity over time needs an animation of two frames or more
        _tick(progress, 0.5)
        sp = fs.sparsity_comparison(model, W)
        out["sparsity"] = {form: {k: float(v) for k, v in vals.items() if np.isscalar(v)}
                           for form, vals in sp.value.items()}
        out["sparsity_message"] = sp.message
    _tick(progress, 0.9)
    img = _coherence_image(f"ShapeSpace Coherence {obj.name}", fs.coherence_image(coherence), png_path)
    out["image"] = img.name
    data["coherence"] = out
    _store(obj, ANALYSIS_PROP, data)
    _tick(progress, 1.0)
    return out


# ------------------------------------------------------------------ the face prior (3.7.9, ch. 6)
def learn_prior(obj, action=None, progress=None) -> dict:
    """Fit the face-space Gaussian to an animation and store it on the rig (names, mean, eigenbasis)."""
    model = linear_model(obj)
    W, frames = animation_weights(obj, model.names, action, min_frames=2)
    _tick(progress, 0.5)
    g = fs.fit_face_gaussian(W)
    data = {"names": model.names, "mean": g.mean.tolist(), "eigvecs": g.eigvecs.tolist(),
            "eigvals": g.eigvals.tolist(), "dimension": g.dimension, "ridge": g.ridge,
            "regularised": g.regularised, "message": g.message, "frames": int(frames.size)}
    _store(obj, PRIOR_PROP, data)
    _tick(progress, 1.0)
    return {"frames": int(frames.size), "dimension": g.dimension, "regularised": g.regularised,
            "message": g.message}


def has_prior(obj) -> bool:
    """Whether ``obj``'s shape keys carry a learnt face prior."""
    key = obj.data.shape_keys if obj is not None and obj.type == "MESH" else None
    return key is not None and PRIOR_PROP in key


def prior(obj):
    """The stored face Gaussian and its slider names, or ``(None, None)``.

    The arrays are checked against each other (``mean`` (n,), ``eigvecs`` (n, n), ``eigvals`` (n,) for the
    ``n`` names, :func:`core.facespace.face_gaussian_from_arrays`): a blob that does not fit is refused as
    damaged, naming the Key and the property.
    """
    data = stored(obj, PRIOR_PROP)
    if "mean" not in data:
        return None, None
    try:
        g = fs.face_gaussian_from_arrays(data["names"], data["mean"], data["eigvecs"], data["eigvals"],
                                         data["dimension"], data["ridge"], data["regularised"], data["message"])
    except ShapeSpaceError as exc:
        raise _damaged(obj.data.shape_keys, PRIOR_PROP, str(exc)) from None
    return g, list(data["names"])


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
    bad = np.flatnonzero(~np.isfinite(w))
    if bad.size:
        raise ShapeSpaceError(f"shape key {names[bad[0]]!r} of {obj.name!r} has value {w[bad[0]]}",
                              ErrorCode.NON_FINITE)
    res = g.plausibility(w[None])
    return {"norm": float(res.diagnostics["norm"][0]), "shell_radius": g.shell_radius,
            "percentile": float(res.diagnostics["percentile"][0]), "status": str(res.value[0])}


def implausible_frames(obj, action=None, alpha: float = 0.01, progress=None) -> list:
    """``[(frame, reason)]`` of an animation's frames outside the prior's typical shell."""
    g, names = _prior_or_error(obj)
    W, frames = animation_weights(obj, names, action)
    _tick(progress, 0.6)
    idx, reasons = g.implausible_frames(W, alpha)
    _tick(progress, 1.0)
    return [(int(frames[i]), r) for i, r in zip(idx, reasons)]


def flag_implausible_frames(obj, action=None, alpha: float = 0.01, progress=None) -> list:
    """:func:`implausible_frames`, also listed in ``obj.shapespace_face.implausible`` for the panel."""
    found = implausible_frames(obj, action, alpha, progress)
    items = obj.shapespace_face.implausible
    items.clear()
    for frame, reason in found:
        item = items.add()
        item.frame, item.reason = frame, reason
    return found


def _finite_ends(obj, action, names, curves, frames, ends, inner_range) -> None:
    """Refuse end expressions (2, n) of a fill that are not finite, naming the curve and the key (keys on
    ``inner_range`` are about to be replaced, so they do not matter)."""
    for j, name in enumerate(names):
        if np.isfinite(ends[:, j]).all():
            continue
        fc = curves.get(name)
        if fc is not None:
            _refuse_non_finite_keys(action, [fc], skip=inner_range)
        _refuse_non_finite_samples(action, fc, np.asarray(frames, float), ends[:, j],
                                   f"shape key {name!r} of {obj.name!r}")


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
    _finite_ends(obj, action, names, actions.shape_key_curves(obj, action), [frame_a, frame_b], ends,
                 (frame_a + 1, frame_b - 1))
    W = fs.interpolate(g, ends[0], ends[1], t, mode)
    for j, name in enumerate(names):
        fc = actions.ensure_fcurve(key, actions.shape_key_path(name))
        actions.replace_keys_between(fc, frame_a + 1, frame_b - 1, inner, W[:, j])
    return int(inner.size)


def keyed_frames(obj) -> np.ndarray:
    """Every keyed frame (k,) of the rig's shape-key curves (repeats included); a key on a NaN or infinite
    frame is refused, naming its curve."""
    curves = actions.shape_key_curves(obj)
    if not curves:
        return np.zeros(0)
    action = actions.active_action(obj.data.shape_keys)
    out = []
    for fc in curves.values():
        kx = actions.read_curve(fc)[0]
        _refuse_non_finite_frames(action, fc, kx)
        out.append(kx)
    return np.concatenate(out)


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


def _sampled_curves(action, target, others, frames, gap, progress) -> np.ndarray:
    """Samples (T, 1 + c) of the target curve and the context curves at ``frames``; the target's known
    samples (outside ``gap``) and every context sample must be finite (refused naming the curve and key)."""
    columns = []
    for i, fc in enumerate([target] + others):
        col = actions.sample_curve(fc, frames)
        known = ~gap if fc is target else np.ones(frames.size, bool)
        if not np.isfinite(col[known]).all():
            skip = (frames[gap][0], frames[gap][-1]) if fc is target and gap.any() else None
            _refuse_non_finite_keys(action, [fc], skip=skip)
            _refuse_non_finite_samples(action, fc, frames[known], col[known])
        columns.append(col)
        _tick(progress, 0.6 * (i + 1) / (1 + len(others)))
    return np.column_stack(columns)


def inpaint_gap(obj, data_path: str, index: int, start: int, end: int, use_other_channels: bool = True,
                progress=None) -> dict:
    """Fill frames ``start … end`` of one F-Curve from the covariance of the rest of the animation
    (9.3), keying every frame of the gap; the known samples outside stay exactly as they were.

    With ``use_other_channels`` the other curves of the action whose motion correlates with the target's
    condition the fill too (superresolution: a knee from the hips), as many as the animation's length
    can support (:func:`core.facespace.fill_gap`).  Keys of the target inside the gap may be damaged (NaN):
    they are replaced.  ``progress`` (optional) is called with the fraction of the work done."""
    owner, action = _curve_owner(obj)
    curves = actions.fcurves(action, owner)
    target = next((fc for fc in curves if fc.data_path == data_path and fc.array_index == index), None)
    if target is None:
        raise ShapeSpaceError(f"{action.name!r} has no curve {data_path}[{index}]", ErrorCode.MISSING_CURVE)
    frames = _integer_frames(action)
    gap = fs.gap_mask(frames, start, end)
    others = [fc for fc in curves if use_other_channels
              and (fc.data_path, fc.array_index) != (target.data_path, target.array_index)]
    X = _sampled_curves(action, target, others, frames, gap, progress)
    res = fs.fill_gap(X, gap)
    _tick(progress, 0.95)
    actions.replace_keys_between(target, start, end, frames[gap], res.value[gap])
    _tick(progress, 1.0)
    return {"frames": int(gap.sum()), "channels": len(res.diagnostics["channels"]),
            "method": res.diagnostics.get("method", ""), "message": res.message}
