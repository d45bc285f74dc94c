"""Keyframes on both action APIs.

Blender 4.2 stores F-Curves directly on the action (``Action.fcurves``).
Blender 4.4+ uses layered actions: ``Action.layers[i].strips[j].channelbags[k]``
hold the F-Curves of one *slot*, and an ID animates through
``AnimData.action`` plus ``AnimData.action_slot``; Blender 5.0 removed
``Action.fcurves``.  This module is the only place that knows the difference.
"""
from __future__ import annotations

import bpy
import numpy as np

from ..core.animation import CONSTANT, LINEAR, sample_keys
from ..core.result import ShapeSpaceError

LAYERED = "slots" in bpy.types.Action.bl_rna.properties
#: Blender 5.0+ ``ActionChannelbagFCurves.new`` takes ``group_name``; 4.4/4.5 do not.
FCURVE_NEW_TAKES_GROUP = LAYERED and "group_name" in bpy.types.ActionChannelbagFCurves.bl_rna.functions[
    "new"].parameters

_INTERP_CODE = {"CONSTANT": CONSTANT, "LINEAR": LINEAR}


def shape_key_path(name: str) -> str:
    """Data path of a shape key's value on its ``Key`` datablock."""
    return f'key_blocks["{bpy.utils.escape_identifier(name)}"].value'


def bone_path(bone: str, channel: str) -> str:
    """Data path of a pose-bone channel (``location``, ``rotation_quaternion``, ...)."""
    return f'pose.bones["{bpy.utils.escape_identifier(bone)}"].{channel}'


def _slot_for(action, id_block):
    """The slot ``id_block`` animates through, or the first slot suited to its type."""
    ad = getattr(id_block, "animation_data", None) if id_block is not None else None
    if ad is not None and ad.action == action and ad.action_slot is not None:
        return ad.action_slot
    id_type = id_block.id_type if id_block is not None else None
    for slot in action.slots:
        if id_type is None or slot.target_id_type in (id_type, "UNSPECIFIED"):
            return slot
    return None


def _channelbag(action, slot, create=False):
    if slot is None:
        return None
    for layer in action.layers:
        for strip in layer.strips:
            bag = strip.channelbag(slot, ensure=create) if create else strip.channelbag(slot)
            if bag is not None:
                return bag
    if not create:
        return None
    layer = action.layers[0] if len(action.layers) else action.layers.new("Layer")
    strip = layer.strips[0] if len(layer.strips) else layer.strips.new(type="KEYFRAME")
    return strip.channelbag(slot, ensure=True)


def fcurves(action, id_block=None) -> list:
    """F-Curves of ``action`` that animate ``id_block`` (or its first suitable slot)."""
    if action is None:
        return []
    if not LAYERED:
        return list(action.fcurves)
    bag = _channelbag(action, _slot_for(action, id_block))
    return list(bag.fcurves) if bag is not None else []


def strip_fcurves(strip, id_block=None) -> list:
    """F-Curves an NLA strip plays on ``id_block``: its action's curves of the strip's own slot (4.4+: one
    action may hold several IDs' slots), of ``id_block``'s first suitable slot when the strip names none."""
    action = strip.action
    if action is None:
        return []
    if not LAYERED:
        return list(action.fcurves)
    slot = getattr(strip, "action_slot", None) or _slot_for(action, id_block)
    bag = _channelbag(action, slot)
    return list(bag.fcurves) if bag is not None else []


def active_fcurves(id_block) -> list:
    """F-Curves of the action ``id_block`` plays directly (through its own slot), [] when none."""
    return fcurves(active_action(id_block), id_block)


def active_action(id_block):
    ad = getattr(id_block, "animation_data", None)
    return ad.action if ad is not None else None


def assign_action(id_block, action) -> None:
    """Make ``id_block`` play ``action`` (creating/assigning a slot on 4.4+)."""
    ad = id_block.animation_data or id_block.animation_data_create()
    ad.action = action
    if LAYERED and ad.action_slot is None:
        slot = _slot_for(action, id_block)
        if slot is None:
            slot = action.slots.new(id_type=id_block.id_type, name=id_block.name)
        ad.action_slot = slot


def new_action(id_block, name: str):
    """Create an empty action, assign it to ``id_block`` and return it."""
    action = bpy.data.actions.new(name)
    if LAYERED:
        slot = action.slots.new(id_type=id_block.id_type, name=id_block.name)
        ad = id_block.animation_data or id_block.animation_data_create()
        ad.action = action
        ad.action_slot = slot
    else:
        assign_action(id_block, action)
    return action


def ensure_fcurve(id_block, data_path: str, index: int = 0, group: str = ""):
    """The F-Curve for ``data_path[index]`` in ``id_block``'s action, created when missing."""
    action = active_action(id_block)
    if action is None:
        action = new_action(id_block, f"{id_block.name}Action")
    if not LAYERED:
        fc = action.fcurves.find(data_path, index=index)
        return fc or action.fcurves.new(data_path, index=index, action_group=group)
    slot = _slot_for(action, id_block)
    if slot is None:
        assign_action(id_block, action)
        slot = id_block.animation_data.action_slot
    bag = _channelbag(action, slot, create=True)
    fc = bag.fcurves.find(data_path, index=index)
    if fc is not None:
        return fc
    if FCURVE_NEW_TAKES_GROUP:
        return bag.fcurves.new(data_path, index=index, group_name=group)
    fc = bag.fcurves.new(data_path, index=index)
    if group:
        fc.group = bag.groups.get(group) or bag.groups.new(group)
    return fc


def write_curve(id_block, data_path: str, frames, values, index: int = 0,
                interpolation: str = "LINEAR", group: str = ""):
    """Replace one curve's keys with ``(frames, values)`` in bulk (``foreach_set``)."""
    frames = np.asarray(frames, dtype=np.float64).ravel()
    values = np.asarray(values, dtype=np.float64).ravel()
    if frames.shape != values.shape:
        raise ShapeSpaceError(f"{frames.size} frames for {values.size} values", "shape")
    if not np.isfinite(values).all() or not np.isfinite(frames).all():
        raise ShapeSpaceError(f"non-finite keys for {data_path}", "non_finite")
    fc = ensure_fcurve(id_block, data_path, index, group)
    fc.keyframe_points.clear()
    fc.keyframe_points.add(frames.size)
    co = np.column_stack([frames, values]).astype(np.float32).ravel()
    fc.keyframe_points.foreach_set("co", co)
    fc.keyframe_points.foreach_set("handle_left", co)
    fc.keyframe_points.foreach_set("handle_right", co)
    code = bpy.types.Keyframe.bl_rna.properties["interpolation"].enum_items[interpolation].value
    fc.keyframe_points.foreach_set("interpolation", np.full(frames.size, code, dtype=np.int32))
    fc.update()
    return fc


def write_bezier_curve(id_block, data_path: str, frames, values, slopes, index: int = 0, group: str = ""):
    """Replace one curve's keys with smooth Bézier keys: value ``values[i]`` at ``frames[i]`` with
    aligned handles along ``slopes[i]`` at a third of each neighbouring segment, so Blender evaluates
    exactly the cubic Hermite of :func:`core.retarget.cloning.hermite`."""
    x = np.asarray(frames, dtype=np.float64).ravel()
    y = np.asarray(values, dtype=np.float64).ravel()
    m = np.asarray(slopes, dtype=np.float64).ravel()
    if not (x.shape == y.shape == m.shape):
        raise ShapeSpaceError(f"{x.size} frames, {y.size} values and {m.size} slopes", "shape")
    if not (np.isfinite(x).all() and np.isfinite(y).all() and np.isfinite(m).all()):
        raise ShapeSpaceError(f"non-finite keys for {data_path}", "non_finite")
    gaps = np.diff(x)
    h_left = np.concatenate([gaps[:1], gaps]) / 3.0 if x.size > 1 else np.ones(1)
    h_right = np.concatenate([gaps, gaps[-1:]]) / 3.0 if x.size > 1 else np.ones(1)
    fc = ensure_fcurve(id_block, data_path, index, group)
    fc.keyframe_points.clear()
    fc.keyframe_points.add(x.size)
    pts = fc.keyframe_points
    pts.foreach_set("co", np.column_stack([x, y]).astype(np.float32).ravel())
    pts.foreach_set("handle_left", np.column_stack([x - h_left, y - m * h_left]).astype(np.float32).ravel())
    pts.foreach_set("handle_right", np.column_stack([x + h_right, y + m * h_right]).astype(np.float32).ravel())
    enum = bpy.types.Keyframe.bl_rna.properties
    aligned = enum["handle_left_type"].enum_items["ALIGNED"].value
    pts.foreach_set("handle_left_type", np.full(x.size, aligned, dtype=np.int32))
    pts.foreach_set("handle_right_type", np.full(x.size, aligned, dtype=np.int32))
    bezier = enum["interpolation"].enum_items["BEZIER"].value
    pts.foreach_set("interpolation", np.full(x.size, bezier, dtype=np.int32))
    fc.update()
    return fc


def replace_keys_between(fc, start: float, end: float, frames, values) -> None:
    """Replace the keys of ``fc`` on ``start … end`` by ``(frames, values)``; every key outside is left
    exactly as it was (value, handles, interpolation).  New keys take the interpolation of the key
    before the range (of the first key when there is none)."""
    pts = fc.keyframe_points
    kx = read_curve(fc)[0]
    before = np.flatnonzero(kx < start)
    interp = pts[int(before[-1])].interpolation if before.size else (pts[0].interpolation if len(pts) else "BEZIER")
    for i in np.flatnonzero((kx >= start) & (kx <= end))[::-1]:
        pts.remove(pts[int(i)], fast=True)
    for f, v in zip(np.asarray(frames, dtype=np.float64), np.asarray(values, dtype=np.float64)):
        kp = pts.insert(float(f), float(v), options={"FAST"})
        kp.interpolation = interp
    fc.update()


def insert_key(id_block, data_path: str, frame: float, value: float, index: int = 0, group: str = ""):
    """Insert (or replace) one key, keeping the curve's other keys."""
    fc = ensure_fcurve(id_block, data_path, index, group)
    kp = fc.keyframe_points.insert(frame, value)  # replaces a key already on that frame
    fc.update()
    return kp


def read_curve(fc):
    """Keys of an F-Curve: frames (m,), values (m,), interpolation names (m,)."""
    pts = fc.keyframe_points
    co = np.empty(len(pts) * 2, dtype=np.float32)
    pts.foreach_get("co", co)
    co = co.reshape(-1, 2).astype(np.float64)
    interp = [kp.interpolation for kp in pts]
    return co[:, 0], co[:, 1], interp


def _exact_in_numpy(fc, interp) -> bool:
    return (len(fc.modifiers) == 0 and len(interp) > 0 and all(i in _INTERP_CODE for i in interp[:-1])
            and not fc.mute)


def sample_curve(fc, frames) -> np.ndarray:
    """Values of ``fc`` at ``frames`` (fractional allowed), float64 (f,).

    CONSTANT/LINEAR curves without modifiers are evaluated in numpy (same
    result as Blender); anything else goes through ``FCurve.evaluate``.
    """
    frames = np.asarray(frames, dtype=np.float64)
    kx, ky, interp = read_curve(fc)
    if _exact_in_numpy(fc, interp):
        codes = [_INTERP_CODE.get(i, LINEAR) for i in interp]
        return sample_keys(kx, ky, codes, frames, extrapolate_linear=fc.extrapolation == "LINEAR")
    return np.array([fc.evaluate(float(f)) for f in frames], dtype=np.float64)


def shape_key_curves(obj, action=None) -> dict:
    """``{shape key name: F-Curve}`` for the keys ``action`` animates on ``obj``'s Key."""
    key = obj.data.shape_keys
    if key is None:
        return {}
    action = action or active_action(key)
    out = {}
    for fc in fcurves(action, key):
        path = fc.data_path
        if path.startswith('key_blocks["') and path.endswith('"].value'):
            name = path[len('key_blocks["'):-len('"].value')].replace('\\"', '"').replace("\\\\", "\\")
            out[name] = fc
    return out


def sample_shape_keys(obj, names, frames, action=None) -> np.ndarray:
    """Shape-key values over time, (f, n); un-animated keys hold their current value."""
    key = obj.data.shape_keys
    curves = shape_key_curves(obj, action)
    frames = np.asarray(frames, dtype=np.float64)
    out = np.empty((frames.size, len(names)))
    for j, name in enumerate(names):
        fc = curves.get(name)
        out[:, j] = sample_curve(fc, frames) if fc is not None else key.key_blocks[name].value
    return out


def key_shape_values(obj, names, frames, values, action_name: str = None, interpolation: str = "LINEAR"):
    """Write dense shape-key animation ``values`` (f, n) at ``frames`` (f,) into a new action."""
    key = obj.data.shape_keys
    values = np.asarray(values, dtype=np.float64)
    action = new_action(key, action_name or f"{obj.name}_ShapeSpace")
    for j, name in enumerate(names):
        write_curve(key, shape_key_path(name), frames, values[:, j], interpolation=interpolation)
    return action


def frame_range(action):
    """(first, last) keyed frame of an action."""
    return tuple(float(f) for f in action.frame_range)


def action_users(action) -> list:
    """Names of the slots (4.4+) or ID root (4.2) the action is meant for."""
    if LAYERED:
        return [s.identifier for s in action.slots]
    return [action.id_root]


def key_sliders(obj, names, frame: float, only_nonzero: bool = False) -> int:
    """Key the current value of each named shape key at ``frame``; return how many were keyed."""
    key = obj.data.shape_keys
    count = 0
    for name in names:
        value = key.key_blocks[name].value
        if only_nonzero and value == 0.0:
            continue
        insert_key(key, shape_key_path(name), frame, value, group="Shape Keys")
        count += 1
    return count


def blender_decimate(id_block, action, curves, error_margin: float) -> None:
    """Run Blender's own Graph Editor *Decimate (Allowed Change)* on ``curves`` of ``action``.

    The reference ShapeSpace's key reduction is compared with.  ``id_block``
    must be animated by ``action`` and be (part of) the active object so the
    Graph Editor lists it; only the keys of ``curves`` are selected.  Works in
    background sessions: an area of the current window's screen is switched to
    the Graph Editor for the call and restored afterwards.
    """
    wanted = {(fc.data_path, fc.array_index) for fc in curves}
    for fc in fcurves(action, id_block):
        on = (fc.data_path, fc.array_index) in wanted
        fc.select = on
        fc.hide = False
        sel = np.full(len(fc.keyframe_points), on, dtype=bool)
        fc.keyframe_points.foreach_set("select_control_point", sel)
    window = bpy.context.window or bpy.context.window_manager.windows[0]
    screen = window.screen
    area = next((a for a in screen.areas if a.type == "GRAPH_EDITOR"), None) or max(
        screen.areas, key=lambda a: a.width * a.height)
    old_type = area.type
    area.type = "GRAPH_EDITOR"
    space = area.spaces.active
    old_only_selected = space.dopesheet.show_only_selected
    space.dopesheet.show_only_selected = False
    try:
        region = next(r for r in area.regions if r.type == "WINDOW")
        with bpy.context.temp_override(window=window, screen=screen, area=area, region=region):
            bpy.ops.graph.decimate(mode="ERROR", remove_error_margin=float(error_margin))
    finally:
        space.dopesheet.show_only_selected = old_only_selected
        area.type = old_type


def action_fcurves(action) -> list:
    """Every F-Curve of ``action``, whatever it animates: all slots' channelbags (4.4+), ``Action.fcurves`` (4.2)."""
    if action is None:
        return []
    if not LAYERED:
        return list(action.fcurves)
    out = []
    for slot in action.slots:
        bag = _channelbag(action, slot)
        out += list(bag.fcurves) if bag is not None else []
    return out
