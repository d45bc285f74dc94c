"""Conversions of a face rig (thesis 3.7.3, 3.4.6): whole-face, delta and PCA copies (new objects; the rig is left
untouched), and Make Convex (the one verb here that changes the rig's slider values)."""
from __future__ import annotations

import bpy
import numpy as np

from ...core import facespace as fs
from ...core import validate
from ...core.errors import ErrorCode
from ...core.facespace.job import convex_step, pca_copy, whole_face_plan
from ...core.facespace.report import ConvexReport
from ...core.result import ShapeSpaceError
from .. import actions, shapekeys, storage
from ..arrays import read_float, write_float
from .readers import animation_weights, linear_model, tick
from .stored import REPRESENTATION_PROP, REPRESENTATION_SCHEMA, damaged

NEUTRAL_KEY = "Neutral"
ZERO_KEY = "Zero"
#: Forms :func:`convert_rig` makes.
FORMS = ("WHOLE_FACE", "DELTA", "PCA")
#: Blender's hard limit of a shape key's value (``slider_min`` ≥ −10, ``slider_max`` ≤ 10): a driven value
#: beyond it is clamped.
SLIDER_LIMIT = 10.0


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
    plan = whole_face_plan(model, convex, SLIDER_LIMIT, repr(obj.name), NEUTRAL_KEY, ZERO_KEY)
    neutral_names = plan.neutral_names
    new = _new_object(obj, "wholeface", np.zeros_like(plan.neutral))
    new.shape_key_add(name=ZERO_KEY, from_mix=False)
    # each Neutral share leads its own run of targets: Blender sums the keys in order in float32, and
    # interleaving keeps that running sum near one face instead of −Σw faces (3–6× less rounding)
    for name, run in zip(neutral_names, plan.runs):
        _add_key(new, name, plan.neutral, ZERO_KEY, -SLIDER_LIMIT, SLIDER_LIMIT)
        for k in run:
            _add_key(new, model.names[k], plan.targets[k], ZERO_KEY, model.slider_min[k], model.slider_max[k])
            tick(progress, 0.9 * (k + 1) / model.n_targets)
    key = new.data.shape_keys
    storage.write_id_blob(key, REPRESENTATION_PROP, REPRESENTATION_SCHEMA,
                          {"form": "whole_face", "source": obj.name, "convex": bool(convex),
                           "neutral_keys": neutral_names})
    if convex:
        for name in neutral_names:
            _convex_driver(key, name, model.names, 1.0 / len(neutral_names))
    else:
        key.key_blocks[NEUTRAL_KEY].value = 1.0
    tick(progress, 1.0)
    return new


def _whole_face_layout(obj) -> tuple:
    """``(metadata, neutral key names)`` of a whole-face copy, checked against its keys."""
    key = obj.data.shape_keys
    meta = storage.read_id_blob(key, REPRESENTATION_PROP, REPRESENTATION_SCHEMA) if key is not None else {}
    if meta.get("form") != "whole_face":
        raise ShapeSpaceError(f"{obj.name!r} is not a whole-face rig made by ShapeSpace", ErrorCode.NOT_WHOLE_FACE)
    names = meta.get("neutral_keys", [NEUTRAL_KEY])
    if not names or not all(isinstance(n, str) for n in names):
        raise damaged(key, REPRESENTATION_PROP, "neutral_keys must be a non-empty list of shape-key names")
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
    tick(progress, 0.1)
    W = None
    if action is not None:
        W, frames = animation_weights(obj, model.names, action, min_frames=2)
        tick(progress, 0.2)
    what = f"the shape keys of {obj.name!r} move" if action is None else f"action {action.name!r} moves"
    basis, sliders = pca_copy(model, W, tol if tol is not None else 1e-3 * model.scale, SLIDER_LIMIT, what)
    tick(progress, 0.7)
    new = _new_object(obj, "pca", sliders.rest)
    new.shape_key_add(name="Mean", from_mix=False)
    names = [f"PC{i + 1:02d}" for i in range(basis.n_components)]
    for i, (name, positions) in enumerate(zip(names, sliders.keys)):
        _add_key(new, name, positions, None, -10.0, 10.0)
        tick(progress, 0.7 + 0.25 * (i + 1) / len(names))
    storage.write_id_blob(new.data.shape_keys, REPRESENTATION_PROP, REPRESENTATION_SCHEMA,
                          {"form": "pca", "source": obj.name, "sliders": model.names,
                           "A": sliders.A.tolist(), "a": sliders.a.tolist()})
    if action is not None:
        actions.key_shape_values(new, names, frames, sliders.slider_values(W), f"{action.name}_pca")
    tick(progress, 1.0)
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


def make_convex(obj) -> ConvexReport:
    """Convex slider mode (3.7.3): move the current slider values to the nearest ones whose whole-face
    weights are a convex combination — each within its range and [0, 1], and Σw ≤ 1 so the neutral's
    weight 1 − Σw stays ≥ 0.  Returns the sum before and after and how far the sliders moved."""
    model = linear_model(obj)
    w = shapekeys.read_slider_values(obj, model.names)
    values, report = convex_step(w, model.slider_min, model.slider_max)
    shapekeys.write_slider_values(obj, model.names, values)
    return report
