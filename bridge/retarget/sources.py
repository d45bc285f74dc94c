"""Retarget sources read from Blender: capture recordings and actions, the head / eye bones, key poses.

A recording (Live Link Face CSV, Face Cap TXT, iFacialMocap, Audio2Face JSON, MediaPipe JSON/CSV) is read by
:func:`core.retarget.read_capture` and resampled to the scene's frames; an action by sampling its shape-key
curves.  Errors about a file start with its path.
"""
from __future__ import annotations

import os
import pathlib
from dataclasses import dataclass

import bpy
import numpy as np

from ...core.errors import ErrorCode
from ...core.headpose import BoneSpec, unused_rotation_channels
from ...core.live import Neutral, calibrate
from ...core.result import Issue, ShapeSpaceError
from ...core.retarget import (
    LearnedCloning,
    key_frames_in_span,
    learned_cloning,
    read_capture,
    resample,
    suggest_key_frames,
)
from .. import actions

__all__ = ["write_pose_bones",
           "KEY_POSE_MARKER", "CAPTURE_EXTENSIONS", "is_capture_file", "read_source", "read_capture_source",
           "bone_specs", "HeadEyeBones", "read_head_eye_bones", "suggest_key_poses", "read_learned"]

KEY_POSE_MARKER = "key pose"
#: File extensions taken for capture recordings (the kind itself is read from the content).
CAPTURE_EXTENSIONS = (".csv", ".txt", ".json")


def is_capture_file(source) -> bool:
    """Whether ``source`` names a capture recording (a file path) rather than an action."""
    if not isinstance(source, (str, os.PathLike)):
        return False
    text = os.fspath(source)
    return text.lower().endswith(CAPTURE_EXTENSIONS) or (bpy.data.actions.get(text) is None
                                                         and os.path.lexists(text))


def read_source(path_or_action, scene) -> tuple:
    """A source as ``(names, scene frames, weights, issues)``: a capture recording's path (Live Link Face CSV,
    Face Cap TXT, iFacialMocap, Audio2Face JSON, MediaPipe JSON/CSV: :func:`core.retarget.read_capture`, the
    kind read from the content) or an action (name).

    A recording's times are resampled to the scene's frame rate starting at the scene's start frame; a take
    (or action) of fewer than 3 scene frames, and NaN or infinite samples, are refused.  Errors about a file
    start with its path.
    """
    if is_capture_file(path_or_action):
        return read_capture_source(path_or_action, scene)[:4]
    action = bpy.data.actions.get(path_or_action) if isinstance(path_or_action, str) else path_or_action
    if action is None:
        raise ShapeSpaceError(f"no CSV file or action named {path_or_action!r}", "missing_source")
    curves = {}
    for fc in actions.action_fcurves(action):
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
    bad = ~np.isfinite(w)
    if bad.any():
        f, j = (int(i) for i in np.argwhere(bad)[0])
        raise ShapeSpaceError(f"action {action.name!r}: the curve of {names[j]!r} is NaN or infinite at frame "
                              f"{frames[f]:g}", ErrorCode.NON_FINITE)
    return names, frames, w, []


def read_capture_source(path, scene) -> tuple:
    """A capture recording resampled to the scene's frames (errors name the file):
    ``(names, frames, weights, issues, rotations (g, 9) or None, kind)`` — the head and eye rotations
    resampled like the weights, when the recording has them."""
    path = os.fspath(path)
    if not os.path.lexists(path):
        raise ShapeSpaceError(f"file not found: {path}", ErrorCode.MISSING_FILE)
    stream = read_capture(pathlib.Path(path))
    rate = scene.render.fps / scene.render.fps_base
    values = stream.weights if stream.rotations is None else np.concatenate([stream.weights, stream.rotations], 1)
    try:
        frames, w = resample(stream.times, values, scene.render.fps, scene.frame_start, scene.render.fps_base)
    except ShapeSpaceError as exc:
        raise ShapeSpaceError(f"{path}: {exc}", exc.code) from None
    if frames.size < 3:
        raise ShapeSpaceError(f"{path}: the take lasts {stream.times[-1]:.3f} s, {frames.size} frame(s) at "
                              f"{rate:g} fps; at least 3 are needed", ErrorCode.TOO_SHORT)
    n = len(stream.names)
    rot = None if stream.rotations is None else w[:, n:]
    return stream.names, frames, w[:, :n], stream.issues, rot, stream.kind


def bone_specs(arm, head: str = "", neck: str = "", eye_left: str = "", eye_right: str = "",
               neck_share: float = 0.3) -> list:
    """The chosen head / neck / eye bones of armature ``arm`` as :class:`core.headpose.BoneSpec` (rest
    orientation, rotation mode); with a neck bone the neck takes ``neck_share`` of the head rotation.  The
    live session and the offline retarget use the same.  A named bone the armature lacks is refused."""
    if arm is None or arm.type != "ARMATURE":
        raise ShapeSpaceError(f"{getattr(arm, 'name', arm)!r} is not an armature", ErrorCode.NOT_ARMATURE)
    share = float(neck_share) if neck else 0.0
    wanted = [(head, "head", 1.0 - share), (neck, "neck", share), (eye_left, "eye_left", 1.0),
              (eye_right, "eye_right", 1.0)]
    bones = []
    for name, part, s in wanted:
        if not name:
            continue
        bone, pb = arm.data.bones.get(name), arm.pose.bones.get(name)
        if bone is None or pb is None:
            raise ShapeSpaceError(f"armature {arm.name!r} has no bone {name!r}", ErrorCode.MISSING_BONE)
        rest = np.array(bone.matrix_local.to_3x3().normalized(), dtype=np.float64)
        bones.append(BoneSpec(name, part, s, rest, pb.rotation_mode))
    return bones


def write_pose_bones(armature: str, bones: list, values: dict) -> str:
    """Set each of ``bones`` (:class:`core.headpose.BoneSpec`) on armature object ``armature`` to ``values[name]``
    in its rotation mode (the live session's per-frame write); '' or why nothing could be written."""
    arm = bpy.data.objects.get(armature)
    if arm is None or arm.type != "ARMATURE":
        return f"the armature {armature!r} was deleted"
    for b in bones:
        pb = arm.pose.bones.get(b.name)
        if pb is not None:
            setattr(pb, b.channel[0], values[b.name])
    return ""


@dataclass
class HeadEyeBones:
    """Which bones a recording's head and eye channels drive offline (as the live session's settings).

    Attributes
    ----------
    armature : str
        The armature object's name ('' for none: the channels are reported unused).
    head, neck, eye_left, eye_right : str
        Bone names ('' for none).
    neck_share : float
        The neck's share of the head rotation (with a neck bone).
    mirror : bool
        A selfie-mirrored capture.
    rest_frame : float or None
        Calibration: the scene frame whose head and eye pose becomes the rest pose (``None``: the captured
        rotations as they are, like live capture before *Calibrate*).
    """

    armature: str = ""
    head: str = ""
    neck: str = ""
    eye_left: str = ""
    eye_right: str = ""
    neck_share: float = 0.3
    mirror: bool = False
    rest_frame: float | None = None


def read_head_eye_bones(settings: HeadEyeBones | None, frames, rotations, report) -> tuple:
    """``(bone specs, calibrated rotations (g, 9) or None, armature name)``; the channels left unused are
    reported by name."""
    chosen = settings is not None and any((settings.head, settings.neck, settings.eye_left, settings.eye_right))
    if chosen and not settings.armature:
        raise ShapeSpaceError("head / neck / eye bones need their armature", ErrorCode.NO_ARMATURE)
    if rotations is None:
        if chosen:
            report.issues.append(Issue("warning", "no_rotation_channels",
                                       "the source has no head or eye channels: no bone was keyed"))
        return [], None, ""
    arm = bpy.data.objects.get(settings.armature) if chosen else None
    if chosen and arm is None:
        raise ShapeSpaceError(f"no armature named {settings.armature!r}", ErrorCode.NO_ARMATURE)
    bones = bone_specs(arm, settings.head, settings.neck, settings.eye_left, settings.eye_right,
                       settings.neck_share) if chosen else []
    unused = unused_rotation_channels(bones, bool(settings and settings.mirror))
    if unused:
        report.issues.append(Issue("warning", "unused_rotation_channels",
                                   f"the source's {', '.join(unused)} channels were not used: "
                                   + ("choose head / neck / eye bones (--head-bone, --neck-bone, --eye-bones)"
                                      if not bones else "no bone takes them"), tuple(unused)))
    if not bones:
        return [], None, ""
    rot = np.asarray(rotations, dtype=np.float64)
    if settings.rest_frame is not None:
        k = int(np.argmin(np.abs(np.asarray(frames) - settings.rest_frame)))
        neutral = Neutral.from_vector(rot[k], 0)
        rot = np.stack([calibrate(v, neutral) for v in rot])
    return bones, rot, arm.name


def suggest_key_poses(source, scene, count: int = None) -> np.ndarray:
    """Scene frames of the source performance worth posing the target at (Chuang–Bregler key poses topped up
    to enough to learn a cloning matrix, :func:`core.retarget.suggest_key_frames`).  Marks them on the
    timeline as ``key pose`` markers, replacing the previous ones."""
    _, frames, src, _ = read_source(source, scene)
    chosen = suggest_key_frames(frames, src, count)
    for m in [m for m in scene.timeline_markers if m.name == KEY_POSE_MARKER]:
        scene.timeline_markers.remove(m)
    for f in chosen:
        scene.timeline_markers.new(KEY_POSE_MARKER, frame=int(f))
    return chosen


def read_learned(obj, model, frames, src, key_pose_action) -> LearnedCloning:
    """Linear expression cloning (3.5.3) from the artist's key poses: the target's shape-key values keyed
    in ``key_pose_action``, against the source at the same frames."""
    if key_pose_action is None:
        raise ShapeSpaceError("the learned method needs the target posed at key frames: key the target's "
                              "shape keys at the suggested key poses in an action and choose it", "no_key_poses")
    action = (bpy.data.actions.get(key_pose_action) if isinstance(key_pose_action, str) else key_pose_action)
    if action is None:
        raise ShapeSpaceError(f"key-pose action {key_pose_action!r} does not exist in this file", "no_key_poses")
    curves = actions.shape_key_curves(obj, action)
    if not curves:
        raise ShapeSpaceError(f"key-pose action {key_pose_action!r} keys none of {obj.name!r}'s shape keys",
                              "no_key_poses")
    keyed = key_frames_in_span(np.concatenate([actions.read_curve(fc)[0] for fc in curves.values()]), frames)
    return learned_cloning(frames, src, keyed, actions.sample_shape_keys(obj, model.names, keyed, action))
