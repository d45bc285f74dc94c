"""Retarget a take onto any rig's controls and key it on the rig's actions (issue #25, item 3).

:func:`retarget_take` = :func:`compute_take` (the rig evaluated through the depsgraph by a
:class:`~bridge.rig.evaluate.RigEvaluator`; each frame solved by :func:`core.rig.take.solve_take`, then, by the
``spacetime`` method, the whole take by Gauss–Newton with the shape-key space-time route's smoothing
(:mod:`core.rig.spacetime`), or by the ``cloning`` method's cloning matrix and refinement (:mod:`core.rig.cloning`))
then :func:`write_take`.  Nothing is written before everything is computed and checked; a failure or
:class:`~core.progress.Cancelled` from ``progress`` leaves the file exactly as it was (the evaluator restores
every channel; actions the rig played are re-attached).

Keys: only the channels that move in the take are keyed ("changed channels"), in a *new* action on each
datablock that owns them — the armature (or other) object for bone channels and custom properties, the mesh's
shape-key datablock for sliders.  The action each one played before is kept (fake user) and
:func:`restore_previous` gives it back (and every channel's value from before the write).  A bone in
``QUATERNION`` or ``AXIS_ANGLE`` mode is keyed on all four components of its rotation, made from its
rotation-vector channels (axes outside the control set keep their value).  ``key_tolerance`` > 0 reduces the
keys (:func:`core.animation.reduce_keys_bezier_curves`, smooth Bézier keys) to the fewest whose curve stays
within ``key_tolerance`` of every frame *in surface units*: each channel's tolerance is ``key_tolerance``
divided by its natural scale (surface motion per unit; quaternion components: half a radian per unit).
While the take is computed the actions of the datablocks that own channels are set aside, so the solve sees the
controls it writes (an action would overwrite them).
"""
from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass, replace

import bpy
import numpy as np

from ...core.errors import ErrorCode
from ...core.keyreduce import reduce_keys_bezier_curves
from ...core.progress import notify, scaled
from ...core.result import ShapeSpaceError
from ...core.retarget.metrics import slider_scales
from ...core.rig import (
    ChannelKind,
    ControlSet,
    RigTakeReport,
    RigTakeResult,
    quaternion_from_rotation_vector,
    solve_take,
    take_report,
)
from ...core.rig.cloning import REFINE_STEPS, solve_take_cloning
from ...core.rig.spacetime import solve_take_spacetime
from ...core.rig.spacetime import take_result as spacetime_take_result
from .. import actions
from ..meshes import world_matrix
from .analytic import key_coords, key_delta
from .channels import EULER_MODES, Binding, bind
from .evaluate import RigEvaluator

__all__ = ["METHODS", "TakeOutcome", "compute_take", "control_sigma", "restore_previous", "rest_controls",
           "retarget_take", "shape_key_targets", "write_take"]

SHAPE_KEY_PREFIX = "data.shape_keys."
#: A channel is keyed when the take moves the surface through it by more than this fraction of the diagonal (or
#: than the key tolerance, when larger: leaving it out keeps every frame within that tolerance).
CHANGED_REL_TOL = 1e-7
#: Default stopping distances of a frame, as fractions of the evaluated mesh's bounding-box diagonal.
PIN_TOL_REL, XTOL_REL = 1e-5, 1e-6
#: Relative precision of Blender's evaluated coordinates (float32), the space-time pass's rounding level.
FLOAT32_EPS = 2.0 ** -24


@dataclass
class TakeOutcome:
    """A computed take, not yet written: the solved controls (F, n) for ``frames`` (F,), the control set with its
    measured natural scales, the core result, the mesh's evaluated diagonal and the name of the new actions."""

    controls: ControlSet
    frames: np.ndarray
    values: np.ndarray
    result: RigTakeResult
    diagonal: float
    action_name: str


def _animated(binding: Binding) -> tuple:
    """(datablock the channel's F-Curve lives on, data path from it) of a channel."""
    ch = binding.channel
    if ch.kind == ChannelKind.SHAPE_KEY and ch.path.startswith(SHAPE_KEY_PREFIX):
        return binding.object.data.shape_keys, ch.path[len(SHAPE_KEY_PREFIX):]
    return binding.object, ch.path


def _ids(bindings) -> list:
    out = []
    for b in bindings:
        idb = _animated(b)[0]
        if all(idb is not o for o in out):
            out.append(idb)
    return out


@contextmanager
def _actions_set_aside(ids):
    """Detach the actions ``ids`` play (drivers stay) for the duration; re-attach them (and their slots)."""
    saved = []
    for idb in ids:
        ad = idb.animation_data
        if ad is not None and ad.action is not None:
            saved.append((idb, ad.action, getattr(ad, "action_slot", None)))
            ad.action = None
    try:
        yield
    finally:
        for idb, action, slot in saved:
            idb.animation_data.action = action
            if slot is not None:
                idb.animation_data.action_slot = slot
        bpy.context.view_layer.update()


def rest_controls(controls: ControlSet) -> np.ndarray:
    """The rest pose of the channels (n,): 0 for rotations, locations, sliders; 1 for scales; a property's
    default; each clipped into its bounds — what the ridge of a take pulls toward by default."""
    out = []
    for b in bind(controls):
        ch = b.channel
        v = 1.0 if ch.kind == ChannelKind.SCALE else 0.0
        if ch.kind == ChannelKind.PROPERTY:
            v = float(b.target.id_properties_ui(b.prop).as_dict().get("default", 0.0))
        out.append(min(max(v, ch.lo), ch.hi))
    return np.array(out, dtype=np.float64)


def shape_key_targets(mesh_obj, names, weights, indices) -> np.ndarray:
    """World-space target positions (F, p, 3) of a shape-key take on the same head: vertices ``indices`` of
    ``mesh_obj``'s basis moved by its relative keys ``names`` (k,) at ``weights`` (F, k) (each key's vertex group
    and relative key honoured), through the object's world matrix — the head's shape keys alone, as a capture's
    weights (ARKit names) play on it, without the rig's bones or drivers."""
    key = mesh_obj.data.shape_keys if mesh_obj.type == "MESH" else None
    if key is None or not key.use_relative:
        raise ShapeSpaceError(f"{mesh_obj.name!r} has no relative shape keys", ErrorCode.MISSING_KEY)
    W = np.asarray(weights, dtype=np.float64)
    names = list(names)
    if W.ndim != 2 or W.shape[1] != len(names):
        raise ShapeSpaceError(f"weights: expected (frames, {len(names)}) for the keys, got {W.shape}",
                              ErrorCode.SHAPE)
    bad = np.argwhere(~np.isfinite(W))
    if bad.size:
        raise ShapeSpaceError(f"weights: frame {bad[0][0]} key {names[bad[0][1]]!r} is not finite",
                              ErrorCode.NON_FINITE)
    idx = np.asarray(indices, dtype=np.int64).reshape(-1)
    if idx.size == 0 or idx.min() < 0 or idx.max() >= len(mesh_obj.data.vertices):
        raise ShapeSpaceError(f"indices: vertices of {mesh_obj.name!r} expected", ErrorCode.PIN)
    cache, deltas = {}, []
    for name in names:
        kb = key.key_blocks.get(name)
        if kb is None or kb == key.reference_key:
            raise ShapeSpaceError(f"{mesh_obj.name!r} has no shape key {name!r}", ErrorCode.MISSING_KEY)
        deltas.append(key_delta(mesh_obj, kb, idx, cache))
    local = key_coords(key.reference_key, idx, cache) + np.einsum("fk,kpi->fpi", W, np.stack(deltas))
    m = world_matrix(mesh_obj)
    return local @ m[:3, :3].T + m[:3, 3]


def _check_take(ev: RigEvaluator, targets, frames) -> tuple:
    t = np.asarray(targets, dtype=np.float64)
    f = np.asarray(frames, dtype=np.float64).reshape(-1)
    if t.ndim != 3 or t.shape[1:] != (ev.indices.size, 3):
        raise ShapeSpaceError(f"targets: expected (frames, {ev.indices.size}, 3) for the {ev.indices.size} "
                              f"vertices, got {t.shape}", ErrorCode.SHAPE)
    if f.size != t.shape[0]:
        raise ShapeSpaceError(f"{f.size} frame numbers for {t.shape[0]} frames of targets", ErrorCode.SHAPE)
    if not np.all(np.isfinite(f)) or np.any(np.diff(f) <= 0):
        raise ShapeSpaceError("frame numbers must be finite and increase strictly", ErrorCode.ORDER)
    return t, f


METHODS = ("perframe", "spacetime", "cloning")


def control_sigma(values: np.ndarray, lo: np.ndarray, hi: np.ndarray, scale: np.ndarray,
                  diagonal: float) -> np.ndarray:
    """Per-control σ of the space-time pass (n,): the shape-key route's per-slider σ
    (:func:`core.retarget.slider_scales`: the spread of the ideal values, floored at a fraction of the range)
    with the per-frame pass's controls ``values`` (F, n) as the ideal; a channel without finite bounds takes as its
    range the motion that moves the surface by a tenth of the diagonal (``0.1 · diagonal / scale``)."""
    rng = np.where(np.isfinite(hi - lo), hi - lo, 0.1 * diagonal / scale)
    return slider_scales(values, np.zeros_like(rng), np.maximum(rng, 1e-12))


def _solve(ev: RigEvaluator, t, r, lo, hi, method, *, reg, smooth, lam, pin_tol, xtol, max_iter, cloning,
           refine_steps, progress):
    """The take's :class:`RigTakeResult` on ``ev`` by ``method`` (:func:`compute_take`)."""
    common = dict(lo=lo, hi=hi, scale=ev.controls.scale, jacobian=ev.jacobian, steps=ev.steps, reg=reg,
                  pin_tol=pin_tol, xtol=xtol)
    if method == "cloning":
        expressions, weights = cloning
        return solve_take_cloning(ev.evaluate, r, expressions, weights, t, refine_steps=refine_steps,
                                  progress=progress, **common)
    split = 1.0 if method == "perframe" else 0.6
    res = solve_take(ev.evaluate, ev.c0, t, rest=r, smooth=smooth, max_iter=max_iter,
                     keep_linearisation=method == "spacetime", progress=scaled(progress, 0.0, split), **common)
    res.diagnostics["jacobians"] = None                           # linearised afresh by the space-time pass
    if method == "perframe":
        return res
    sigma = control_sigma(res.value, lo, hi, ev.controls.scale, ev.diagonal)
    st = solve_take_spacetime(ev.evaluate, res.value, res.diagnostics["points"], None, t, sigma,
                              jacobian=ev.jacobian, lo=lo, hi=hi, rest=r, lam=lam, xtol=0.1 * xtol,
                              precision=FLOAT32_EPS * float(np.abs(res.diagnostics["points"]).max()),
                              progress=scaled(progress, split, 1.0))
    return spacetime_take_result(res, st, t)


def compute_take(mesh_obj, controls: ControlSet, indices, targets, frames, *, reg: float = 1e-6,
                 smooth: float = 0.0, rest=None, pin_tol: float | None = None, xtol: float | None = None,
                 max_iter: int = 20, action_name: str | None = None, method: str = "perframe",
                 lam: float = 1e-7, cloning: tuple | None = None, refine_steps: int = REFINE_STEPS,
                 progress=None) -> TakeOutcome:
    """Solve every frame of a take (module doc); nothing is written, the rig is left exactly as it was.

    Parameters
    ----------
    mesh_obj : bpy.types.Object
        The deformed mesh.
    controls : ControlSet
    indices : array_like of int (p,)
        Vertices whose world-space targets are given.
    targets : array_like (F, p, 3)
        World-space target positions per frame.
    frames : array_like (F,)
        Scene frame of each row (strictly increasing).
    reg, smooth, max_iter
        As in :func:`core.rig.take.solve_take`.
    rest : array_like (n,), optional
        What the ridge pulls toward (:func:`rest_controls` by default).
    pin_tol, xtol : float, optional
        Stopping distances (default 1e-5 and 1e-6 of the evaluated mesh's diagonal).
    method : str
        ``'perframe'`` (:func:`core.rig.take.solve_take`), ``'spacetime'`` (the per-frame pass, then Gauss–Newton
        on the whole take with the shape-key space-time route's smoothing: :mod:`core.rig.spacetime`, σ from
        :func:`control_sigma`, relative λ ``lam``) or ``'cloning'`` (:mod:`core.rig.cloning`; needs ``cloning``).
    lam : float
        The space-time λ, relative as the retarget command's ``--lam``.
    cloning : tuple, optional
        ``(expressions (k, p, 3), weights (F, k))``: each source expression's world-space target at the vertices
        and the source's weights per frame (the cloning route).
    refine_steps : int
        The cloning route's refinement steps per frame.
    progress : callable, optional
        ``progress(fraction)``; raising :class:`~core.progress.Cancelled` stops the take.
    """
    if method not in METHODS:
        raise ShapeSpaceError(f"method {method!r}: expected one of {', '.join(METHODS)}", ErrorCode.METHOD)
    if method == "cloning" and cloning is None:
        raise ShapeSpaceError("the cloning route needs the source's expressions and weights", ErrorCode.METHOD)
    name = action_name or f"{mesh_obj.name} rig take"
    r = rest_controls(controls) if rest is None else controls.vector(rest, "rest")
    with _actions_set_aside(_ids(bind(controls))):
        notify(progress, 0.0)
        with RigEvaluator(mesh_obj, controls, indices) as ev:
            t, f = _check_take(ev, targets, frames)
            if method == "spacetime" and t.shape[0] < 3:
                raise ShapeSpaceError(f"space-time needs a take of at least 3 frames, got {t.shape[0]}",
                                      ErrorCode.RANGE)
            lo, hi = ev.controls.solve_bounds(ev.c0)
            d = ev.diagonal
            res = _solve(ev, t, np.clip(r, lo, hi), lo, hi, method, reg=reg, smooth=smooth, lam=lam,
                         pin_tol=PIN_TOL_REL * d if pin_tol is None else pin_tol,
                         xtol=XTOL_REL * d if xtol is None else xtol, max_iter=max_iter, cloning=cloning,
                         refine_steps=refine_steps, progress=scaled(progress, 0.05, 1.0))
            res.diagnostics["rig_evaluations"] = ev.evaluations
            res.diagnostics.setdefault("method", method)
            return TakeOutcome(ev.controls, f, res.value, res, d, name)


# -- keys ---------------------------------------------------------------------------------------------------------

def _curves(outcome: TakeOutcome, bindings, key_tolerance: float) -> tuple:
    """Every curve to key: ``([(datablock, path, index, group, values (F,), surface units per value unit)],
    keyed channel names)`` — channels that move, quaternion / axis-angle bones as four components."""
    C, s = outcome.values, outcome.controls.scale
    current = np.array([b.get() for b in bindings])
    moved = np.abs(C - current).max(0) * s > max(CHANGED_REL_TOL * outcome.diagonal, key_tolerance)
    curves, keyed, grouped = [], [], {}
    for j, b in enumerate(bindings):
        ch = b.channel
        idb, path = _animated(b)
        group = path.split('"')[1] if path.startswith("pose.bones[") else ""
        if ch.kind == ChannelKind.ROTATION and ch.rotation_mode not in EULER_MODES:
            grouped.setdefault((idb.as_pointer(), path), []).append(j)
            continue
        if moved[j]:
            curves.append((idb, path, max(ch.index, 0), group, C[:, j], s[j]))
            keyed.append(ch.name)
    for cols in grouped.values():
        if not moved[cols].any():
            continue
        b = bindings[cols[0]]
        idb, path = _animated(b)
        rv = np.tile([Binding(replace(b.channel, index=k)).get() for k in range(3)], (C.shape[0], 1))
        for j in cols:
            rv[:, bindings[j].channel.index] = C[:, j]
        comps = _rotation_components(rv, b.channel.rotation_mode)
        for k in range(4):
            curves.append((idb, path, k, path.split('"')[1], comps[:, k], 2.0 * s[cols].max()))
        keyed += [bindings[j].channel.name for j in cols]
    return curves, keyed


def _rotation_components(rv: np.ndarray, mode: str) -> np.ndarray:
    """Rotation vectors (F, 3) as quaternions (w, x, y, z) on one hemisphere from frame to frame, or as axis
    angles (angle, x, y, z) keeping the previous axis through a zero angle; (F, 4)."""
    out = np.empty((rv.shape[0], 4))
    axis = np.array([0.0, 1.0, 0.0])
    for i, v in enumerate(rv):
        if mode == "QUATERNION":
            q = quaternion_from_rotation_vector(v)
            out[i] = -q if i and q @ out[i - 1] < 0 else q
        else:
            angle = float(np.linalg.norm(v))
            axis = v / angle if angle > 1e-12 else axis
            out[i] = np.r_[angle, axis]
    return out


def _reduce(curves, frames, tol: float, progress=None) -> tuple:
    """Keys per curve: ``[(frames, values, slopes or None)]`` and the fraction of dense keys kept."""
    if tol <= 0 or not curves:
        notify(progress, 1.0)
        return [(frames, c[4], None) for c in curves], 1.0
    units = np.array([c[5] for c in curves])
    V = np.column_stack([c[4] for c in curves]) * units
    reduced = reduce_keys_bezier_curves(frames, V, tol, progress=progress)
    keys = [(frames[i], kv / u, sl / u) for (i, kv, sl), u in zip(reduced, units)]
    return keys, sum(len(k[0]) for k in keys) / (len(frames) * len(curves))


def _previous(idb) -> dict:
    ad = idb.animation_data
    action = ad.action if ad is not None else None
    slot = getattr(ad, "action_slot", None) if ad is not None else None
    return {"id": "KEY" if isinstance(idb, bpy.types.Key) else "OBJECT", "name": idb.name, "action": "",
            "previous": action.name if action is not None else "",
            "previous_slot": getattr(slot, "identifier", "") or "",
            "had_animation_data": ad is not None,
            "previous_fake_user": bool(action.use_fake_user) if action is not None else False}


def _id_block(entry: dict):
    coll = bpy.data.shape_keys if entry["id"] == "KEY" else bpy.data.objects
    return coll.get(entry["name"])


def _give_back(idb, entry: dict) -> None:
    """``idb`` plays what it played before (action, slot, fake-user flag); the new action is deleted unless something
    else plays it now."""
    made = bpy.data.actions.get(entry["action"]) if entry["action"] else None
    previous = bpy.data.actions.get(entry["previous"]) if entry["previous"] else None
    ad = idb.animation_data
    if previous is not None:
        actions.assign_action(idb, previous)
        slot = next((sl for sl in getattr(previous, "slots", ()) if sl.identifier == entry["previous_slot"]), None)
        if slot is not None:
            idb.animation_data.action_slot = slot
        previous.use_fake_user = entry["previous_fake_user"]
    elif ad is not None and not entry["had_animation_data"] and not ad.drivers:
        idb.animation_data_clear()
    elif ad is not None:
        ad.action = None
    if made is not None and made is not previous and made.users - int(made.use_fake_user) == 0:
        bpy.data.actions.remove(made)                  # kept when something else plays it now


def write_take(outcome: TakeOutcome, key_tolerance: float = 0.0, progress=None) -> RigTakeReport:
    """Key the computed take (module doc) in one step and return its report; on any failure while writing every
    datablock gets back the action it played and the new actions are deleted (the file is as before)."""
    if not (np.isfinite(key_tolerance) and key_tolerance >= 0):
        raise ShapeSpaceError(f"key tolerance {key_tolerance} must be a non-negative number", ErrorCode.RANGE)
    if not np.all(np.isfinite(outcome.values)):
        raise ShapeSpaceError("the solved controls came out NaN or infinite; nothing was written",
                              ErrorCode.NON_FINITE)
    bindings = bind(outcome.controls)
    report = take_report(outcome.result, outcome.frames, outcome.controls.names)
    curves, report.keyed_channels = _curves(outcome, bindings, key_tolerance)
    keys, report.key_fraction = _reduce(curves, outcome.frames, key_tolerance, progress)
    report.values_before = [list(v) if isinstance(v, tuple) else v for v in (b.raw() for b in bindings)]
    ids = []
    for c in curves:
        if all(c[0] is not o for o in ids):
            ids.append(c[0])
    entries = [_previous(idb) for idb in ids]
    try:
        for idb, entry in zip(ids, entries):
            name = outcome.action_name if len(ids) == 1 else f"{outcome.action_name} {idb.name}"
            entry["action"] = actions.new_action(idb, name).name
            for (owner, path, index, group, *_), (x, y, slopes) in zip(curves, keys):
                if owner is not idb:
                    continue
                if slopes is None:
                    actions.write_curve(idb, path, x, y, index=index, group=group)
                else:
                    actions.write_bezier_curve(idb, path, x, y, slopes, index=index, group=group)
    except BaseException:
        for idb, entry in zip(ids, entries):
            _give_back(idb, entry)
        raise
    for entry in entries:
        bpy.data.actions[entry["action"]].use_fake_user = True
        if entry["previous"]:
            bpy.data.actions[entry["previous"]].use_fake_user = True
    report.actions = entries
    bpy.context.view_layer.update()
    return report


def retarget_take(mesh_obj, controls: ControlSet, indices, targets, frames, *, reg: float = 1e-6,
                  smooth: float = 0.0, rest=None, key_tolerance: float = 0.0, pin_tol: float | None = None,
                  xtol: float | None = None, max_iter: int = 20, action_name: str | None = None,
                  method: str = "perframe", lam: float = 1e-7, progress=None) -> RigTakeReport:
    """:func:`compute_take` (``method`` ``'perframe'`` or ``'spacetime'``) then :func:`write_take` (module doc);
    ``progress`` over both."""
    outcome = compute_take(mesh_obj, controls, indices, targets, frames, reg=reg, smooth=smooth, rest=rest,
                           pin_tol=pin_tol, xtol=xtol, max_iter=max_iter, action_name=action_name, method=method,
                           lam=lam, progress=scaled(progress, 0.0, 0.95))
    return write_take(outcome, key_tolerance, scaled(progress, 0.95, 1.0))


def restore_previous(report: RigTakeReport, controls: ControlSet) -> None:
    """Undo :func:`write_take`: every datablock it keyed plays the action it played before (slot, fake-user flag),
    the take's actions are deleted and each channel of ``controls`` gets its value from before the write.
    Refused (nothing changed) when a datablock no longer plays the take's action or the previous action is gone."""
    plan = []
    for entry in report.actions:
        idb = _id_block(entry)
        if idb is None:
            raise ShapeSpaceError(f"{entry['name']!r} is no longer in the file: nothing was restored",
                                  ErrorCode.MISSING_OBJECT)
        playing = actions.active_action(idb)
        if playing is None or playing.name != entry["action"]:
            raise ShapeSpaceError(f"{idb.name!r} no longer plays the take's action {entry['action']!r}: nothing "
                                  "was restored", ErrorCode.NO_ACTION)
        if entry["previous"] and entry["previous"] not in bpy.data.actions:
            raise ShapeSpaceError(f"the action {entry['previous']!r} {idb.name!r} played before is gone: nothing "
                                  "was restored", ErrorCode.NO_ACTION)
        plan.append((idb, entry))
    bindings = bind(controls)
    if len(report.values_before) != len(bindings):
        raise ShapeSpaceError(f"the report holds {len(report.values_before)} channel values for "
                              f"{len(bindings)} channels: nothing was restored", ErrorCode.SHAPE)
    for idb, entry in plan:
        _give_back(idb, entry)
    for b, raw in zip(bindings, report.values_before):
        b.set_raw(tuple(raw) if isinstance(raw, list) else raw)
    bpy.context.view_layer.update()
