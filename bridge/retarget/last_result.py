"""The last retarget's result, remembered on the target's Key: its report, and *Discard Result*.

The report (the keys of :data:`REPORT_KEYS` that apply) is kept in the Key's :data:`LAST_PROP` custom property
(versioned JSON, :data:`LAST_SCHEMA`) for the panel and *Discard Result*.  *Discard Result* only ever restores:
it refuses when the rig no longer plays the result or when the action to restore is gone.
"""
from __future__ import annotations

import math

import bpy

from ...core import blobs
from ...core.errors import ErrorCode
from ...core.result import ShapeSpaceError
from ...core.retarget import RetargetReport
from .. import actions, storage

__all__ = ["LAST_PROP", "REPORT_KEYS", "LAST_SCHEMA", "has_result", "last_report", "discard_last"]

#: Key custom property: the last retarget's report (the keys of :data:`REPORT_KEYS` that apply).
LAST_PROP = "shapespace_last_retarget"
REPORT_KEYS = ("source", "method", "frames", "mapped_channels", "position_error_mm", "velocity_error_mm",
               "position_error_rms", "velocity_error_rms", "clipping_frames", "clipped_frames", "frame_range",
               "scene_range_extended", "scene_range_before", "keys_kept_frac", "converged", "action",
               "previous_action", "previous_fake_user", "bones", "bones_action", "armature", "armature_previous")
LAST_SCHEMA = blobs.RETARGET_LAST.schema


def _key(obj):
    return obj.data.shape_keys if obj is not None and obj.type == "MESH" else None


def has_result(obj) -> bool:
    """Whether ``obj``'s Key keeps a retarget result (that *Discard Result* can undo)."""
    key = _key(obj)
    return key is not None and LAST_PROP in key


def last_report(obj) -> RetargetReport | None:
    """The last retarget's report kept on ``obj``'s Key (``None`` when there is none)."""
    if not has_result(obj):
        return None
    data = storage.read_id_blob(_key(obj), LAST_PROP, LAST_SCHEMA)
    data.pop("schema_version", None)
    return RetargetReport.from_json(data)


def _restore_scene_range(rep: RetargetReport, scene) -> None:
    """Give ``scene`` the frame range it had before the retarget widened it — only when the range is still
    exactly what the retarget made it (a range the artist changed since is theirs)."""
    if not rep.scene_range_extended or not rep.scene_range_before or not rep.frame_range or scene is None:
        return
    start, end = (int(v) for v in rep.scene_range_before)
    made = (min(start, math.floor(rep.frame_range[0])), max(end, math.ceil(rep.frame_range[1])))
    if (scene.frame_start, scene.frame_end) == made:
        scene.frame_start = start
        scene.frame_end = end


def discard_last(obj, scene=None) -> str:
    """Undo the last retarget's result: give the rig back the action it played before (with its fake-user
    flag as it was), delete the retargeted action if nothing else uses it, and give ``scene`` (default: the
    current one) the frame range it had if the retarget widened it and it is unchanged since.  Returns the
    restored action's name ('' for none).

    Only ever restores: refused (nothing changed) when the rig no longer plays the result, or when the
    action to restore is no longer in the file (e.g. a file saved by ShapeSpace 0.1.0 that lost it).
    """
    rep = last_report(obj)
    if rep is None:
        raise ShapeSpaceError(f"{obj.name!r} has no retarget result to discard", "no_result")
    key = obj.data.shape_keys
    made = bpy.data.actions.get(rep.action) if rep.action else None
    current = actions.active_action(key)
    if current is not None and current != made:
        raise ShapeSpaceError(f"{obj.name!r} plays {current.name!r}, not the retarget result {rep.action!r}: "
                              "nothing was discarded", ErrorCode.NO_RESULT)
    previous = bpy.data.actions.get(rep.previous_action) if rep.previous_action else None
    if rep.previous_action and previous is None:
        raise ShapeSpaceError(f"the action {rep.previous_action!r} that {rep.action!r} replaced is no longer in "
                              "the file: nothing was discarded (the result is kept)", ErrorCode.NO_ACTION)
    arm_plan = _armature_discard_plan(rep)
    if previous is not None:
        actions.assign_action(key, previous)
        if rep.previous_fake_user is not None:
            previous.use_fake_user = rep.previous_fake_user
    elif key.animation_data is not None:
        key.animation_data.action = None
    if made is not None and made != previous and made.users - int(made.use_fake_user) == 0:
        bpy.data.actions.remove(made)
    if arm_plan is not None:
        _discard_bones(*arm_plan)
    _restore_scene_range(rep, scene or bpy.context.scene)
    del key[LAST_PROP]
    return previous.name if previous is not None else ""


def _armature_discard_plan(rep: RetargetReport):
    """What Discard Result gives the armature back, checked before anything changes: ``(armature, bones
    action, previous action or None, previous slot identifier, previous fake user)``; None when no bones were
    keyed (or the armature is gone).  Refused when the armature no longer plays the result's bones or the
    action it played before is gone."""
    if not rep.armature or not rep.bones_action or not rep.armature_previous:
        return None
    arm = bpy.data.objects.get(rep.armature)
    if arm is None:
        return None
    bones_action = bpy.data.actions.get(rep.bones_action)
    playing = arm.animation_data.action if arm.animation_data is not None else None
    if playing is not None and playing != bones_action:
        raise ShapeSpaceError(f"the armature {arm.name!r} plays {playing.name!r}, not the retarget's bone keys "
                              f"{rep.bones_action!r}: nothing was discarded", ErrorCode.NO_RESULT)
    name, slot, fake = rep.armature_previous
    previous = bpy.data.actions.get(name) if name else None
    if name and previous is None:
        raise ShapeSpaceError(f"the action {name!r} the armature {arm.name!r} played before is no longer in the "
                              "file: nothing was discarded (the result is kept)", ErrorCode.NO_ACTION)
    return arm, bones_action, previous, slot, fake


def _discard_bones(arm, bones_action, previous, slot: str, fake: bool) -> None:
    """Give the armature back what it played (action, slot, fake-user flag); delete a bones action nothing
    else uses (on 4.2 the bones have an action of their own)."""
    if previous is not None:
        actions.assign_action(arm, previous)
        ad = arm.animation_data
        if slot and hasattr(ad, "action_slot"):
            match = next((sl for sl in previous.slots if sl.identifier == slot), None)
            if match is not None:
                ad.action_slot = match
        previous.use_fake_user = bool(fake)
    elif arm.animation_data is not None:
        arm.animation_data.action = None
    if bones_action is not None and bones_action.users - int(bones_action.use_fake_user) == 0:
        bpy.data.actions.remove(bones_action)
