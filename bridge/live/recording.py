"""Recording live takes into actions, and the list of takes.

Record creates a new action (with a fake user, so it survives a save even when
nothing plays it) holding one F-Curve per slider and per driven bone channel;
every scene frame the stream completes is appended as a key immediately, so
the take so far is always in the action — Stop, unregistering the add-on or
closing Blender mid-take keeps it.  While recording the action is not assigned
(the animation system would otherwise override the live values); Stop
Recording makes the rig play it.  Blender 4.4+ keeps the sliders and the bones
in one action (a slot each); 4.2 uses a second action for the bones.

Each take action carries its metadata (``shapespace_live_take``): source, the
source timecode of its first frame, scene rate and first frame, frame count,
method, target, and whether it was completed.
"""
from __future__ import annotations

import bpy
import numpy as np

from ...core import blobs
from ...core.errors import ErrorCode
from ...core.keyreduce import reduce_keys_bezier
from ...core.result import ShapeSpaceError
from ...core.retarget import retarget_weights
from .. import actions, retarget, shapekeys, storage

__all__ = ["TAKE_PROP", "TAKE_SCHEMA", "TakeRecorder", "is_take", "take_info", "takes", "unique_take_name",
           "play_take", "remove_take", "clean_take"]

TAKE_PROP = blobs.LIVE_TAKE.prop
TAKE_SCHEMA = blobs.LIVE_TAKE.schema
BONE_SUFFIX = " bones"


def is_take(action) -> bool:
    """Whether ``action`` is a live take."""
    return action is not None and TAKE_PROP in action


def take_info(action) -> dict:
    """The take's metadata (see :data:`TAKE_SCHEMA`)."""
    data = storage.read_id_blob(action, TAKE_PROP, TAKE_SCHEMA)
    data.pop("schema_version", None)
    return data


def takes() -> list:
    """Names of every take action in the file, in name order."""
    return sorted(a.name for a in bpy.data.actions if is_take(a))


def unique_take_name(base: str) -> str:
    """``base 1``, ``base 2``, …: the first name no action has."""
    base = (base or "Take").strip() or "Take"
    k = 1
    while bpy.data.actions.get(f"{base} {k}") is not None or bpy.data.actions.get(f"{base} {k}{BONE_SUFFIX}"):
        k += 1
    return f"{base} {k}"


def _curve_channels(slider_names, bones) -> tuple:
    """``[(data path, index)]`` of the key's sliders and of the bones' rotation channels."""
    keys = [(actions.shape_key_path(n), 0) for n in slider_names]
    bone_channels = [(actions.bone_path(b.name, b.channel[0]), i) for b in bones for i in range(b.channel[1])]
    return keys, bone_channels


def _make_curves(id_block, action, channels, group: str) -> None:
    """Create the (empty) F-Curves of ``channels`` for ``id_block`` in ``action`` without leaving it assigned."""
    previous = actions.active_action(id_block)
    actions.assign_action(id_block, action)
    try:
        for path, index in channels:
            actions.ensure_fcurve(id_block, path, index, group)
    finally:
        if previous is not None:
            actions.assign_action(id_block, previous)
        else:
            id_block.animation_data.action = None


class TakeRecorder:
    """Appends solved frames to a take action, key by key (the take so far is always in the file).

    Holds names only (looked up on every write: undo-safe).
    """

    def __init__(self, pipeline, name: str, meta: dict) -> None:
        obj = bpy.data.objects.get(pipeline.target)
        if obj is None or obj.type != "MESH" or obj.data.shape_keys is None:
            raise ShapeSpaceError(f"the target {pipeline.target!r} is gone (or has no shape keys)",
                                  ErrorCode.MISSING_TARGET)
        key = obj.data.shape_keys
        self.target, self.armature = pipeline.target, pipeline.armature
        self.key_channels, self.bone_channels = _curve_channels(pipeline.slider_names, pipeline.bones)
        self.bone_order = [b.name for b in pipeline.bones]
        action = bpy.data.actions.new(name)
        action.use_fake_user = True
        self.action = action.name
        _make_curves(key, action, self.key_channels, "Shape Keys")
        self.bones_action = ""
        arm = bpy.data.objects.get(self.armature) if self.armature else None
        if arm is not None and self.bone_channels:
            bones_action = action
            if not actions.LAYERED:              # 4.2: an action animates one kind of ID
                bones_action = bpy.data.actions.new(name + BONE_SUFFIX)
                bones_action.use_fake_user = True
                self.bones_action = bones_action.name
            _make_curves(arm, bones_action, self.bone_channels, "Live")
        self.frames = 0
        self.meta = dict(meta, frames=0, complete=False, armature=self.armature, bones_action=self.bones_action)
        storage.write_id_blob(action, TAKE_PROP, TAKE_SCHEMA, self.meta)

    def _curves(self, action_name: str, id_name: str, channels: list, collection) -> list:
        action = bpy.data.actions.get(action_name)
        owner = collection.get(id_name) if id_name else None
        if action is None or owner is None:
            return []
        id_block = owner.data.shape_keys if owner.type == "MESH" else owner
        by_path = {(fc.data_path, fc.array_index): fc for fc in actions.fcurves(action, id_block)}
        return [by_path.get(c) for c in channels]

    def add(self, samples: list) -> str:
        """Append ``[(scene frame, sliders (n,), {bone: values})]``; returns '' or why recording must stop."""
        if not samples:
            return ""
        if bpy.data.actions.get(self.action) is None:
            return f"the take {self.action!r} was removed (undo?); recording stopped"
        key_curves = self._curves(self.action, self.target, self.key_channels, bpy.data.objects)
        if not key_curves or any(fc is None for fc in key_curves):
            return f"the take {self.action!r} or its target {self.target!r} changed; recording stopped"
        for frame, sliders, _ in samples:
            _append(key_curves, frame, sliders)
        if self.bone_channels:
            curves = self._curves(self.bones_action or self.action, self.armature, self.bone_channels,
                                  bpy.data.objects)
            if curves and all(fc is not None for fc in curves):
                for frame, _, bones in samples:
                    _append(curves, frame, [v for name in self.bone_order for v in bones.get(name, ())])
        self.frames += len(samples)
        return ""

    def finish(self, complete: bool = True, play: bool = True) -> str:
        """Store the final metadata and (``play``) make the rig (and armature) play the take; returns the
        take's name."""
        action = bpy.data.actions.get(self.action)
        if action is None:
            return ""
        for fc in actions.action_fcurves(action):
            fc.update()
        self.meta.update(frames=self.frames, complete=complete)
        storage.write_id_blob(action, TAKE_PROP, TAKE_SCHEMA, self.meta)
        if not play:
            return self.action
        try:
            play_take(self.action)
        except ShapeSpaceError:          # the target is gone: the take stays in the file, unassigned
            pass
        return self.action


def _append(curves: list, frame: float, values) -> None:
    """One LINEAR key per curve at ``frame`` (handles on the key, as the offline dense writer makes them)."""
    for fc, v in zip(curves, values):
        pts = fc.keyframe_points
        pts.add(1)
        kp = pts[-1]
        kp.co = kp.handle_left = kp.handle_right = (frame, float(v))
        kp.interpolation = "LINEAR"


def play_take(name: str) -> None:
    """Make the take's target (and armature) play it."""
    action = bpy.data.actions.get(name)
    if not is_take(action):
        raise ShapeSpaceError(f"no live take named {name!r}", ErrorCode.MISSING_SOURCE)
    info = take_info(action)
    obj = bpy.data.objects.get(info["target"])
    if obj is None or obj.type != "MESH" or obj.data.shape_keys is None:
        raise ShapeSpaceError(f"the take's target {info['target']!r} is gone", ErrorCode.MISSING_TARGET)
    actions.assign_action(obj.data.shape_keys, bpy.data.actions.get(info.get("clean_action", "")) or action)
    arm = bpy.data.objects.get(info.get("armature", "")) if info.get("armature") else None
    if arm is not None:
        if actions.LAYERED:
            bones = bpy.data.actions.get(info.get("clean_action", "")) or action
        else:
            bones = bpy.data.actions.get(info.get("clean_bones_action", "")) or \
                bpy.data.actions.get(info.get("bones_action", ""))
        if bones is not None and actions.fcurves(bones, arm):
            actions.assign_action(arm, bones)


def remove_take(name: str) -> None:
    """Delete a take (and its bones / cleaned actions)."""
    action = bpy.data.actions.get(name)
    if not is_take(action):
        raise ShapeSpaceError(f"no live take named {name!r}", ErrorCode.MISSING_SOURCE)
    info = take_info(action)
    extras = ("bones_action", "clean_action", "clean_bones_action")
    for extra in (info.get(k, "") for k in extras):
        other = bpy.data.actions.get(extra) if extra else None
        if other is not None:
            bpy.data.actions.remove(other)
    bpy.data.actions.remove(action)


def clean_take(name: str, spacetime: bool, key_tolerance: float) -> str:
    """The offline passes on a recorded take, into a new action ``<take> clean`` (the raw take is kept).

    ``spacetime``: the sliders refitted by space-time cloning (thesis ch. 5) so motion beyond the slider
    ranges keeps its shape; ``key_tolerance`` > 0: the fewest smooth keys within that slider error.
    Returns the new action's name.
    """
    action = bpy.data.actions.get(name)
    if not is_take(action):
        raise ShapeSpaceError(f"no live take named {name!r}", ErrorCode.MISSING_SOURCE)
    info = take_info(action)
    obj = bpy.data.objects.get(info["target"])
    if obj is None or obj.type != "MESH" or obj.data.shape_keys is None:
        raise ShapeSpaceError(f"the take's target {info['target']!r} is gone", ErrorCode.MISSING_TARGET)
    key = obj.data.shape_keys
    curves = {fc.data_path: fc for fc in actions.fcurves(action, key)}
    model = shapekeys.read_blendshape_model(obj)
    names = [n for n in model.names if actions.shape_key_path(n) in curves]
    if not names or info["frames"] < 3:
        raise ShapeSpaceError(f"the take {name!r} has {info['frames']} frames; at least 3 are needed",
                              ErrorCode.TOO_SHORT)
    frames = actions.read_curve(curves[actions.shape_key_path(names[0])])[0]
    W = np.stack([actions.read_curve(curves[actions.shape_key_path(n)])[1] for n in names], axis=1)
    if spacetime:
        if not model.is_linear:
            raise ShapeSpaceError(retarget.NONLINEAR_MESSAGE, ErrorCode.NONLINEAR)
        full = np.zeros((frames.size, model.n_targets))
        full[:, [model.names.index(n) for n in names]] = W
        W = retarget_weights(model, full, "spacetime").weights[:, [model.names.index(n) for n in names]]
    clean = actions.new_action(key, f"{name} clean")
    clean.use_fake_user = True
    if key_tolerance > 0:
        retarget.reduce_action_keys(obj, names, frames, W, key_tolerance, "BEZIER")
    else:
        for j, n in enumerate(names):
            actions.write_curve(key, actions.shape_key_path(n), frames, W[:, j])
    _clean_bones(dict(info, take=name), clean, key_tolerance)
    info["clean_action"] = clean.name
    storage.write_id_blob(action, TAKE_PROP, TAKE_SCHEMA, info)
    play_take(name)
    return clean.name


def _clean_bones(info: dict, clean, key_tolerance: float) -> None:
    """Copy the take's bone curves into the cleaned take (key-reduced too when asked)."""
    arm = bpy.data.objects.get(info.get("armature", "")) if info.get("armature") else None
    raw = bpy.data.actions.get(info.get("bones_action", "")) if info.get("bones_action") else None
    if arm is None:
        return
    take = bpy.data.actions.get(info.get("take", ""))
    source = raw or take
    curves = [(fc.data_path, fc.array_index, *actions.read_curve(fc)[:2]) for fc in actions.fcurves(source, arm)] \
        if source is not None else []
    if not curves:
        return
    target = clean if actions.LAYERED else bpy.data.actions.new(clean.name + BONE_SUFFIX)
    target.use_fake_user = True
    previous = actions.active_action(arm)
    actions.assign_action(arm, target)
    for path, index, x, y in curves:
        if key_tolerance > 0 and x.size >= 3:
            idx, values, slopes = reduce_keys_bezier(x, y, key_tolerance)
            actions.write_bezier_curve(arm, path, x[idx], values, slopes, index=index)
        else:
            actions.write_curve(arm, path, x, y, index=index)
    if target is not clean:
        info["clean_bones_action"] = target.name
    if previous is not None:
        actions.assign_action(arm, previous)
