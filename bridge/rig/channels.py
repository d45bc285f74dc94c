"""Read a rig's channels (pose bones, custom properties, shape-key sliders) as a :class:`core.rig.ControlSet`,
and write control values back to them.

Bounds come from the rig itself:

- a pose bone's Euler rotation axis: its Limit Rotation constraint (enabled, full influence, owner space
  ``LOCAL`` and Euler order ``AUTO`` or the bone's own: then the constraint's range is exactly the channel's);
  a ``QUATERNION``/``AXIS_ANGLE`` bone's rotation-vector axis: [−π, π];
- location / scale axes: Limit Location / Limit Scale constraints (same conditions);
- custom properties: the property's soft range (``id_properties_ui``; the hard range when no soft one);
- shape-key sliders: ``slider_min`` / ``slider_max``.

Lock flags are the bone's ``lock_rotation`` / ``lock_location`` / ``lock_scale``.  Constraints in other spaces
are not turned into bounds (the evaluator's probe still finds a channel they hold still).
"""
from __future__ import annotations

import math

import bpy
import numpy as np

from ...core.errors import ErrorCode
from ...core.result import ShapeSpaceError
from ...core.rig import (
    Channel,
    ChannelKind,
    ControlSet,
    quaternion_from_rotation_vector,
    rotation_vector_from_quaternion,
)

__all__ = ["Binding", "bind", "bone_channel", "bone_channels", "control_set", "property_channel",
           "shape_key_channel"]

EULER_MODES = ("XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX")
AXES = "XYZ"
_ROT_PATH = {"QUATERNION": "rotation_quaternion", "AXIS_ANGLE": "rotation_axis_angle"}
_LIMITS = {ChannelKind.ROTATION: "LIMIT_ROTATION", ChannelKind.LOCATION: "LIMIT_LOCATION",
           ChannelKind.SCALE: "LIMIT_SCALE"}


def _object(name: str):
    ob = bpy.data.objects.get(name)
    if ob is None:
        raise ShapeSpaceError(f"no object {name!r}", ErrorCode.MISSING_OBJECT)
    return ob


def _pose_bone(arm_obj, bone_name: str):
    if arm_obj.type != "ARMATURE":
        raise ShapeSpaceError(f"{arm_obj.name!r} is not an armature", ErrorCode.NOT_ARMATURE)
    pb = arm_obj.pose.bones.get(bone_name)
    if pb is None:
        raise ShapeSpaceError(f"armature {arm_obj.name!r} has no bone {bone_name!r}", ErrorCode.MISSING_BONE)
    return pb


def _constraint_bounds(pb, kind: ChannelKind, axis: int) -> tuple:
    """(lo, hi) the bone's Limit constraints put on one axis of a channel of ``kind`` (infinite when none)."""
    lo, hi = -math.inf, math.inf
    a = AXES[axis].lower()
    for con in pb.constraints:
        if con.type != _LIMITS[kind] or con.mute or con.influence < 1.0 or con.owner_space != "LOCAL":
            continue
        if kind == ChannelKind.ROTATION:
            if getattr(con, "euler_order", "AUTO") not in ("AUTO", pb.rotation_mode):
                continue
            if getattr(con, f"use_limit_{a}"):
                lo, hi = max(lo, getattr(con, f"min_{a}")), min(hi, getattr(con, f"max_{a}"))
        else:
            if getattr(con, f"use_min_{a}"):
                lo = max(lo, getattr(con, f"min_{a}"))
            if getattr(con, f"use_max_{a}"):
                hi = min(hi, getattr(con, f"max_{a}"))
    if lo > hi:
        lo = hi = 0.5 * (lo + hi)
    return lo, hi


def bone_channel(arm_obj, bone_name: str, kind: str, axis: int) -> Channel:
    """One axis of a pose bone's rotation (in its rotation mode), location or scale, with bounds and lock.

    Parameters
    ----------
    arm_obj : bpy.types.Object
        The armature object.
    bone_name : str
    kind : {"rotation", "location", "scale"}
    axis : {0, 1, 2}
    """
    kind = ChannelKind(kind)
    if kind not in _LIMITS or axis not in (0, 1, 2):
        raise ShapeSpaceError(f"bone {bone_name!r}: no {kind.value} channel {axis}", ErrorCode.MISSING_CHANNEL)
    pb = _pose_bone(arm_obj, bone_name)
    label = f"{bone_name} {kind.value} {AXES[axis]}"
    bone = f'pose.bones["{bpy.utils.escape_identifier(bone_name)}"]'
    if kind == ChannelKind.ROTATION:
        mode = pb.rotation_mode
        if mode in EULER_MODES:
            lo, hi = _constraint_bounds(pb, kind, axis)
            path = f"{bone}.rotation_euler"
        else:
            lo, hi = -math.pi, math.pi
            path = f"{bone}.{_ROT_PATH[mode]}"
        return Channel(label, kind, arm_obj.name, path, axis, lo, hi, bool(pb.lock_rotation[axis]), mode)
    lo, hi = _constraint_bounds(pb, kind, axis)
    return Channel(label, kind, arm_obj.name, f"{bone}.{kind.value}", axis, lo, hi,
                   bool(getattr(pb, f"lock_{kind.value}")[axis]))


def bone_channels(arm_obj, bone_names, kinds=("rotation",)) -> list:
    """The unlocked channels of ``kinds`` of each bone in ``bone_names`` (a proposal; locked axes left out)."""
    out = []
    for name in bone_names:
        for kind in kinds:
            for axis in range(3):
                ch = bone_channel(arm_obj, name, kind, axis)
                if not ch.locked:
                    out.append(ch)
    return out


def property_channel(obj, prop: str, bone_name: str | None = None) -> Channel:
    """A float custom property of an object (or of one of its pose bones) with its soft range as bounds."""
    owner = _pose_bone(obj, bone_name) if bone_name is not None else obj
    where = f"bone {bone_name!r}" if bone_name is not None else f"object {obj.name!r}"
    if prop not in owner.keys():
        raise ShapeSpaceError(f"{where} has no custom property {prop!r}", ErrorCode.MISSING_PROPERTY)
    if not isinstance(owner[prop], float):
        raise ShapeSpaceError(f"custom property {prop!r} of {where} is not a float ({type(owner[prop]).__name__})",
                              ErrorCode.TYPE)
    ui = owner.id_properties_ui(prop).as_dict()
    lo = ui.get("soft_min", ui.get("min", -math.inf))
    hi = ui.get("soft_max", ui.get("max", math.inf))
    ident = f'["{bpy.utils.escape_identifier(prop)}"]'
    path = (f'pose.bones["{bpy.utils.escape_identifier(bone_name)}"]{ident}' if bone_name is not None else ident)
    label = f"{bone_name}[{prop}]" if bone_name is not None else f"{obj.name}[{prop}]"
    return Channel(label, ChannelKind.PROPERTY, obj.name, path, -1, float(lo), float(hi))


def shape_key_channel(obj, key_name: str) -> Channel:
    """A shape-key slider of a mesh object with its slider range as bounds."""
    keys = obj.data.shape_keys if obj.type == "MESH" else None
    kb = keys.key_blocks.get(key_name) if keys is not None else None
    if kb is None or kb == keys.reference_key:
        raise ShapeSpaceError(f"{obj.name!r} has no shape-key slider {key_name!r}", ErrorCode.MISSING_KEY)
    path = f'data.shape_keys.key_blocks["{bpy.utils.escape_identifier(key_name)}"].value'
    return Channel(f"key {key_name}", ChannelKind.SHAPE_KEY, obj.name, path, -1, kb.slider_min, kb.slider_max)


def control_set(channels) -> ControlSet:
    """A :class:`ControlSet` of the given channels (in order)."""
    return ControlSet(tuple(channels))


# -- reading and writing values ---------------------------------------------------------------------------------

def _split_prop(path: str) -> tuple:
    """``'pose.bones["b"]["p"]'`` → (``'pose.bones["b"]'``, ``'p'``); ``'["p"]'`` → (``''``, ``'p'``)."""
    head, _, tail = path.rpartition('["')
    return head, tail[:-2].replace('\\"', '"').replace("\\\\", "\\")


class Binding:
    """Reads and writes one channel's value on Blender data (resolved once).

    ``raw()`` / ``set_raw()`` save and restore the underlying property exactly (all components of a bone's
    rotation, location or scale; the property or slider value) — :class:`~bridge.rig.evaluate.RigEvaluator`
    restores a rig from them.
    """

    def __init__(self, channel: Channel):
        self.channel = channel
        self.object = _object(channel.owner)
        kind = channel.kind
        if kind == ChannelKind.PROPERTY:
            head, self.prop = _split_prop(channel.path)
            self.target = self.object.path_resolve(head) if head else self.object
            self.attr = None
        else:
            head, _, self.attr = channel.path.rpartition(".")
            self.target = self.object.path_resolve(head)
            self.prop = None
        self.id_data = self.object

    # exact state of the underlying property
    def raw(self):
        if self.prop is not None:
            return self.target[self.prop]
        value = getattr(self.target, self.attr)
        return value if isinstance(value, float) else tuple(value)

    def set_raw(self, value) -> None:
        if self.prop is not None:
            self.target[self.prop] = value
            self.id_data.update_tag()
        else:
            setattr(self.target, self.attr, value)

    # the channel's value
    def get(self) -> float:
        ch = self.channel
        if self.prop is not None:
            return float(self.target[self.prop])
        value = getattr(self.target, self.attr)
        if ch.index < 0:
            return float(value)
        if ch.kind == ChannelKind.ROTATION and ch.rotation_mode not in EULER_MODES:
            return float(self._rotation_vector()[ch.index])
        return float(value[ch.index])

    def set(self, v: float) -> None:
        ch = self.channel
        if self.prop is not None:
            self.target[self.prop] = float(v)
            self.id_data.update_tag()
        elif ch.index < 0:
            setattr(self.target, self.attr, float(v))
        elif ch.kind == ChannelKind.ROTATION and ch.rotation_mode not in EULER_MODES:
            rv = self._rotation_vector()
            rv[ch.index] = v
            self._set_rotation_vector(rv)
        else:
            getattr(self.target, self.attr)[ch.index] = float(v)

    def _rotation_vector(self) -> np.ndarray:
        value = np.array(getattr(self.target, self.attr), dtype=np.float64)
        if self.attr == "rotation_quaternion":
            return rotation_vector_from_quaternion(value)
        axis = value[1:]
        norm = np.linalg.norm(axis)
        return np.zeros(3) if norm == 0.0 else value[0] * axis / norm

    def _set_rotation_vector(self, rv) -> None:
        if self.attr == "rotation_quaternion":
            self.target.rotation_quaternion = tuple(quaternion_from_rotation_vector(rv))
            return
        angle = float(np.linalg.norm(rv))
        axis = (0.0, 1.0, 0.0) if angle == 0.0 else tuple(np.asarray(rv) / angle)
        self.target.rotation_axis_angle = (angle,) + axis


def bind(controls: ControlSet) -> list:
    """One :class:`Binding` per channel (refuses a channel whose owner or data path does not resolve)."""
    out = []
    for ch in controls.channels:
        try:
            out.append(Binding(ch))
        except (ValueError, KeyError, AttributeError) as exc:
            if isinstance(exc, ShapeSpaceError):
                raise
            raise ShapeSpaceError(f"channel {ch.name!r}: {ch.owner}.{ch.path} does not resolve",
                                  ErrorCode.MISSING_CHANNEL) from exc
    return out
