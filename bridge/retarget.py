"""Retargeting onto a shape-key rig: sources read from Blender, results written back (thesis 3.5, ch. 5).

Blender I/O and orchestration only — the numerics (cloning, per-frame and
space-time fits, dense transfer, errors) are in :mod:`core.retarget`, key
reduction in :mod:`core.animation`.  Sources are Live Link Face CSV files,
actions and animated meshes; every result is a new action on the target's Key,
with its :class:`~core.retarget.RetargetReport` kept on the Key (for the panel
and *Discard Result*) next to the channel-mapping overrides.

Nothing is lost: everything is validated and computed (keys included, checked
finite) before the first write, and a failure while writing removes the new
action and gives the rig back what it played.  Every result action has a fake
user (a batch of results all survive saving), and the action a result displaces
gets one too (whether it had one is remembered; *Discard Result* restores it).
*Discard Result* only ever restores: it refuses when the rig no longer plays the
result or when the action to restore is gone.
"""
from __future__ import annotations

import math
import os
import pathlib
from dataclasses import dataclass

import bpy
import numpy as np

from ..core.animation import reduce_keys, reduce_keys_bezier_curves
from ..core.blendshape import BlendshapeModel
from ..core.errors import ErrorCode
from ..core.headpose import BoneSpec, bone_curves, unused_rotation_channels
from ..core.live import Neutral, calibrate
from ..core.jobs import BackgroundJob
from ..core.names import match_channels
from ..core.progress import notify, scaled
from ..core.result import ShapeSpaceError
from ..core.retarget import (GEOMETRIC_METHODS, METHODS, LearnedCloning, RetargetReport, copy_weights,
                             key_frames_in_span, learned_cloning, peak_landmarks, read_capture, resample,
                             retarget_positions, retarget_weights, split_mapping, stabilise, suggest_key_frames,
                             transfer_motion)
from ..core.retarget.performance import check_dense_budget, check_finite_weights
from ..core import blobs
from ..core.validate import choice, non_negative, positive
from . import actions, shapekeys, storage

__all__ = ["METHODS", "KEY_SHAPES", "read_source", "read_capture_source", "is_capture_file",
           "channel_mapping", "resolve_mapping", "suggest_key_poses",
           "retarget", "retarget_dense", "RetargetPlan", "RetargetOutcome", "read_retarget", "read_retarget_dense",
           "compute_retarget", "write_retarget", "start_retarget_job", "finish_retarget_job",
           "reduce_action_keys", "last_report", "has_result", "discard_last",
           "stored_mapping", "set_mapping", "remove_mapping", "landmark_pairs", "mesh_sequence",
           "dense_source_positions", "add_landmark", "landmarks_from_shapes", "selected_vertex"]

KEY_POSE_MARKER = "key pose"
#: File extensions taken for capture recordings (the kind itself is read from the content).
CAPTURE_EXTENSIONS = (".csv", ".txt", ".json")
KEY_SHAPES = ("BEZIER", "LINEAR")
NONLINEAR_MESSAGE = ("the target has in-between or combination shapes, so its face is not linear in the sliders: "
                     "fit methods cannot use it; retarget with copy or learned (the driven shapes follow)")

#: Key custom property: the channel-mapping overrides ``{source channel: {target, gain, offset}}``.
MAPPING_PROP = "shapespace_mapping"
MAPPING_SCHEMA = blobs.RETARGET_MAPPING.schema

#: Largest magnitude of a mapping override's gain or offset.
MAX_MAPPING_VALUE = 100.0

#: Key custom property: the last retarget's report (the keys of :data:`REPORT_KEYS` that apply).
LAST_PROP = "shapespace_last_retarget"
REPORT_KEYS = ("source", "method", "frames", "mapped_channels", "position_error_mm", "velocity_error_mm",
               "position_error_rms", "velocity_error_rms", "clipping_frames", "clipped_frames", "frame_range",
               "scene_range_extended", "scene_range_before", "keys_kept_frac", "converged", "action",
               "previous_action", "previous_fake_user", "bones", "bones_action", "armature", "armature_previous")
LAST_SCHEMA = blobs.RETARGET_LAST.schema

LANDMARK_PREFIX = "lm_"
STABLE_GROUP = "stable"


# ------------------------------------------------------------------ sources
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


def _head_eye_plan(settings: HeadEyeBones | None, frames, rotations, report) -> tuple:
    """``(bone specs, calibrated rotations (g, 9) or None, armature name)``; the channels left unused are
    reported by name."""
    chosen = settings is not None and any((settings.head, settings.neck, settings.eye_left, settings.eye_right))
    if chosen and not settings.armature:
        raise ShapeSpaceError("head / neck / eye bones need their armature", ErrorCode.NO_ARMATURE)
    if rotations is None:
        if chosen:
            report.issues.append("the source has no head or eye channels: no bone was keyed")
        return [], None, ""
    arm = bpy.data.objects.get(settings.armature) if chosen else None
    if chosen and arm is None:
        raise ShapeSpaceError(f"no armature named {settings.armature!r}", ErrorCode.NO_ARMATURE)
    bones = bone_specs(arm, settings.head, settings.neck, settings.eye_left, settings.eye_right,
                       settings.neck_share) if chosen else []
    unused = unused_rotation_channels(bones, bool(settings and settings.mirror))
    if unused:
        report.issues.append(f"the source's {', '.join(unused)} channels were not used: "
                             + ("choose head / neck / eye bones (--head-bone, --neck-bone, --eye-bones)"
                                if not bones else "no bone takes them"))
    if not bones:
        return [], None, ""
    rot = np.asarray(rotations, dtype=np.float64)
    if settings.rest_frame is not None:
        k = int(np.argmin(np.abs(np.asarray(frames) - settings.rest_frame)))
        neutral = Neutral.from_vector(rot[k], 0)
        rot = np.stack([calibrate(v, neutral) for v in rot])
    return bones, rot, arm.name


def channel_mapping(obj, source_names, target_names) -> list:
    """``[(source index, target index, gain, offset)]``: stored overrides first, then name matching
    (:func:`resolve_mapping` without its warnings)."""
    return resolve_mapping(obj, source_names, target_names)[0]


def resolve_mapping(obj, source_names, target_names) -> tuple:
    """The channel mapping and its warnings: ``([(source index, target index, gain, offset)], [str])``.

    Stored overrides win over name matching.  An override whose target key no longer exists (stale) is
    reported by name, and its channel is matched by name when that is possible; an override with a NaN or
    infinite gain or offset is refused naming the channel.
    """
    stored = stored_mapping(obj)
    auto, _, _ = match_channels(source_names, target_names)
    live, stale = {}, {}
    for name, entry in stored.items():
        if name not in source_names:
            continue
        gain, offset = float(entry.get("gain", 1.0)), float(entry.get("offset", 0.0))
        if not all(math.isfinite(v) and abs(v) <= MAX_MAPPING_VALUE for v in (gain, offset)):
            raise ShapeSpaceError(f"the channel mapping of {name!r} has a non-finite or out-of-range gain or offset "
                                  f"({gain:g}, {offset:g}): fix it with Set Channel Mapping", ErrorCode.NON_FINITE)
        (live if entry.get("target") in target_names else stale)[name] = (entry.get("target"), gain, offset)
    claimed = {target for target, _, _ in live.values()}           # overrides win
    out, warnings = [], []
    for i, s in enumerate(source_names):
        if s in live:
            target, gain, offset = live[s]
            out.append((i, target_names.index(target), gain, offset))
            continue
        by_name = auto.get(s) if auto.get(s) not in claimed else None
        if s in stale:
            what = (f"{s} was matched by name to {by_name}" if by_name is not None
                    else f"{s} is not retargeted (fix or remove the override)")
            warnings.append(f"the channel mapping {s} → {stale[s][0]} names no shape key of {obj.name!r}: {what}")
        if by_name is not None:
            out.append((i, target_names.index(by_name), 1.0, 0.0))
    if not out:
        raise ShapeSpaceError("the source and the target share no channels (check the names or the mapping)",
                              "no_mapping")
    return out, warnings


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


def _learned(obj, model, frames, src, key_pose_action) -> LearnedCloning:
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


# ------------------------------------------------------------------ retarget
# Three steps, so a modal operator can run the middle one in a worker thread (core.jobs.BackgroundJob):
#   read_retarget (main thread: everything from Blender) → compute_retarget (pure numerics, no Blender data,
#   progress + Cancelled) → write_retarget (main thread: one step, nothing written before it).

@dataclass
class RetargetPlan:
    """Everything a retarget needs, read from Blender (:func:`read_retarget`); no Blender references.

    ``raw`` is the unbounded weight performance on the target's sliders when it is already known (learned);
    ``pairs``/``gain``/``offset`` with ``source_weights`` give it by copying (copy and the fits of a weight
    source); ``dense`` holds a mesh performance's transfer inputs.
    """

    obj_name: str
    method: str
    lam: float
    key_tolerance: float
    key_shape: str
    action_name: str
    extend_scene_range: bool
    model: BlendshapeModel
    paths: list
    frames: np.ndarray
    report: RetargetReport
    rig: tuple
    raw: np.ndarray | None = None
    source_weights: np.ndarray | None = None
    pairs: list | None = None
    gain: np.ndarray | None = None
    offset: np.ndarray | None = None
    dense: dict | None = None
    bones: list | None = None
    rotations: np.ndarray | None = None
    armature: str = ""
    mirror: bool = False


@dataclass
class RetargetOutcome:
    """A computed retarget (:func:`compute_retarget`): the report and every curve to write, checked finite."""

    plan: RetargetPlan
    weights: np.ndarray
    curves: list
    report: RetargetReport
    bone_curves: list | None = None


def _rig_signature(obj) -> tuple:
    """What the computed result depends on and a user could change while it computes: the mode, the vertex
    count, and the shape keys' names and slider ranges."""
    key = obj.data.shape_keys
    blocks = [] if key is None else key.key_blocks
    return (obj.mode, len(obj.data.vertices), tuple((kb.name, kb.slider_min, kb.slider_max) for kb in blocks))


def read_retarget(obj, source, method: str = "spacetime", scene=None, lam: float = 1e-7,
                  key_tolerance: float = 0.0, action_name: str = None, key_shape: str = "BEZIER",
                  key_pose_action=None, extend_scene_range: bool = True,
                  bones: HeadEyeBones | None = None) -> RetargetPlan:
    """Step 1 of :func:`retarget` (main thread): validate the settings and read the rig and ``source`` (capture
    recording or action), the channel mapping or the learned map, and the head / eye bones (``bones``).
    Changes nothing."""
    choice(method, "method", METHODS)
    lam, key_tolerance = _settings(lam, key_tolerance, key_shape)
    scene = scene or bpy.context.scene
    model = shapekeys.read_blendshape_model(obj)
    if not model.is_linear and method in GEOMETRIC_METHODS:
        raise ShapeSpaceError(NONLINEAR_MESSAGE, "nonlinear")
    rotations = None
    if is_capture_file(source):
        names, frames, src, issues, rotations, _ = read_capture_source(source, scene)
    else:
        names, frames, src, issues = read_source(source, scene)
    report = RetargetReport(source=str(source), method=method, frames=int(frames.size),
                            issues=[i.message for i in issues])
    plan = RetargetPlan(obj.name, method, lam, key_tolerance, key_shape, action_name or f"{obj.name}_{method}",
                        bool(extend_scene_range), model, [actions.shape_key_path(n) for n in model.names],
                        np.asarray(frames, dtype=np.float64), report, _rig_signature(obj))
    plan.bones, plan.rotations, plan.armature = _head_eye_plan(bones, frames, rotations, report)
    plan.mirror = bool(bones is not None and bones.mirror)
    if method == "learned":     # the artist's key poses define the map: no channel names needed
        learned = _learned(obj, model, frames, src, key_pose_action)
        plan.raw = learned.weights                                                # unbounded ideal
        report.key_poses, report.learned_fit_rms = learned.key_poses, learned.fit_rms
        report.mapped_channels = learned.mapped_channels
    else:
        mapping, warnings = resolve_mapping(obj, names, model.names)
        report.issues += warnings
        plan.pairs, plan.gain, plan.offset = split_mapping(mapping, model.n_targets)
        plan.source_weights = src
        report.mapped_channels = len(plan.pairs)
    return plan


def read_retarget_dense(obj, source_obj, method: str = "spacetime", scene=None, lam: float = 1e-7,
                        key_tolerance: float = 0.0, action_name: str = None, key_shape: str = "BEZIER",
                        extend_scene_range: bool = True, progress=None) -> RetargetPlan:
    """Step 1 of :func:`retarget_dense` (main thread): validate, read the rig and the mesh performance's
    evaluated positions over the scene range (``progress`` per frame).  Gives the scene its current frame
    back; changes nothing else."""
    if method not in GEOMETRIC_METHODS:
        raise ShapeSpaceError("a mesh performance needs a geometric method: perframe or spacetime", "method")
    lam, key_tolerance = _settings(lam, key_tolerance, key_shape)
    scene = scene or bpy.context.scene
    model = shapekeys.read_blendshape_model(obj)
    if not model.is_linear:
        raise ShapeSpaceError(NONLINEAR_MESSAGE, "nonlinear")
    frames = np.arange(scene.frame_start, scene.frame_end + 1, dtype=np.float64)
    if frames.size < 3:
        raise ShapeSpaceError(f"the scene range has {frames.size} frames; at least 3 are needed", "too_short")
    check_dense_budget(frames.size, max(len(source_obj.data.vertices), model.n_vertices), "a mesh performance")
    report = RetargetReport(source=source_obj.name, method=method, frames=int(frames.size), issues=[])
    plan = RetargetPlan(obj.name, method, lam, key_tolerance, key_shape,
                        action_name or f"{obj.name}_{source_obj.name}", bool(extend_scene_range), model,
                        [actions.shape_key_path(n) for n in model.names], frames, report, _rig_signature(obj))
    plan.dense = _dense_inputs(source_obj, model, obj, scene, frames, progress)
    return plan


def _shares(plan: RetargetPlan) -> tuple:
    """Fractions of the progress bar at which compute_retarget's stages end: (copy, transfer, fit)."""
    keys = 0.0 if plan.key_tolerance <= 0 else (0.3 if plan.method in GEOMETRIC_METHODS else 0.85)
    if plan.dense is not None:
        return 0.0, 0.15, 1.0 - keys
    return 0.02, 0.02, 1.0 - keys


def compute_retarget(plan: RetargetPlan, progress=None) -> RetargetOutcome:
    """Step 2 of :func:`retarget` (any thread; touches no Blender data): the fit and every curve to write.

    ``progress(fraction)`` (:mod:`core.progress`) is called through the copy, the fit (by the solver) and the
    key reduction (per curve); raising :class:`~core.progress.Cancelled` from it stops the work.
    """
    copy_end, transfer_end, fit_end = _shares(plan)
    model, report = plan.model, plan.report
    if plan.dense is not None:
        positions = _dense_positions(plan.dense, model)
        notify(progress, transfer_end)
        fit = retarget_positions(model, positions, plan.method, plan.lam,
                                 progress=scaled(progress, transfer_end, fit_end))
    else:
        raw = plan.raw
        if raw is None:
            raw = copy_weights(plan.source_weights, plan.pairs, model.n_targets, plan.gain, plan.offset,
                               progress=scaled(progress, 0.0, copy_end))
        check_finite_weights(raw, model.names, "the mapped source")
        fit = retarget_weights(model, raw, plan.method, plan.lam, progress=scaled(progress, copy_end, fit_end))
    report.record(fit, plan.frames)
    check_finite_weights(fit.weights, model.names, "the retarget")
    curves, kept = _plan_curves(model.names, plan.paths, plan.frames, fit.weights, plan.key_tolerance,
                                plan.key_shape, scaled(progress, fit_end, 1.0))
    if plan.key_tolerance > 0:
        report.keys_kept_frac = kept
    outcome = RetargetOutcome(plan, fit.weights, curves, report, _bone_plan(plan))
    notify(progress, 1.0)
    return outcome


def _bone_plan(plan: RetargetPlan) -> list | None:
    """The bones' curves, as the live session keys them (:func:`core.headpose.bone_curves`), with the weight
    curves' key reduction: ``[(data path, index, bone, frames, values, slopes or None)]`` (no Blender data)."""
    if not plan.bones:
        return None
    values = bone_curves(plan.rotations, plan.bones, plan.mirror)
    columns, labels, paths = [], [], []
    for b in plan.bones:
        prop, count = b.channel
        for i in range(count):
            columns.append(values[b.name][:, i])
            labels.append(f"{b.name} {prop}[{i}]")
            paths.append((actions.bone_path(b.name, prop), i, b.name))
    planned, _ = _plan_curves(labels, [p for p, _, _ in paths], plan.frames, np.stack(columns, axis=1),
                              plan.key_tolerance, plan.key_shape)
    return [(path, index, bone, x, y, slopes) for (path, index, bone), (_, x, y, slopes) in zip(paths, planned)]


def write_retarget(outcome: RetargetOutcome, scene=None) -> RetargetReport:
    """Step 3 of :func:`retarget` (main thread): write the result in one step.

    Refused, with nothing written, when the rig is gone or changed (mode, vertices, shape keys or slider
    ranges) since :func:`read_retarget`.  Widens the scene's frame range to the frames written unless the plan
    says not to."""
    plan = outcome.plan
    obj = bpy.data.objects.get(plan.obj_name)
    if obj is None or obj.type != "MESH" or _rig_signature(obj) != plan.rig:
        raise ShapeSpaceError(f"{plan.obj_name!r} changed while the retarget computed (mode, mesh, shape keys or "
                              "slider ranges): nothing was written; retarget again", ErrorCode.RIG_CHANGED)
    arm = bpy.data.objects.get(plan.armature) if outcome.bone_curves else None
    if outcome.bone_curves and (arm is None or arm.type != "ARMATURE"
                                or any(arm.pose.bones.get(b.name) is None for b in plan.bones)):
        raise ShapeSpaceError(f"the armature {plan.armature!r} or its bones changed while the retarget computed: "
                              "nothing was written; retarget again", ErrorCode.RIG_CHANGED)
    return _write_result(obj, outcome.curves, plan.action_name, outcome.report,
                         scene or bpy.context.scene, plan.extend_scene_range, (arm, outcome.bone_curves))


def start_retarget_job(plan: RetargetPlan) -> BackgroundJob:
    """Start :func:`compute_retarget` of ``plan`` in a worker thread (a modal operator polls the job, and
    cancels it on Esc); :func:`finish_retarget_job` writes its outcome once it is done."""
    return BackgroundJob(lambda progress: compute_retarget(plan, progress), name="ShapeSpace retarget").start()


def finish_retarget_job(job: BackgroundJob, scene=None) -> RetargetReport:
    """Write a finished job's outcome (main thread, one step) and return its report.

    Re-raises what stopped the job (:class:`~core.progress.Cancelled` when it was cancelled, its
    :class:`ShapeSpaceError`); nothing is written then."""
    try:
        outcome = job.result()
    except MemoryError:
        raise ShapeSpaceError("not enough memory for this retarget (split the take, or use the copy method)",
                              ErrorCode.TOO_LARGE) from None
    return write_retarget(outcome, scene)


def retarget(obj, source, method: str = "spacetime", scene=None, lam: float = 1e-7, key_tolerance: float = 0.0,
             action_name: str = None, key_shape: str = "BEZIER", key_pose_action=None,
             extend_scene_range: bool = True, progress=None, bones: HeadEyeBones | None = None) -> RetargetReport:
    """Retarget ``source`` (capture recording or action) onto ``obj``'s sliders and write a new action; with
    ``bones``, the recording's head and eye channels key those bones in the same action set.

    Everything is validated and computed before the first write; on any failure (or
    :class:`~core.progress.Cancelled` from ``progress``) the file is as before.  The scene's frame range is
    widened to the frames written unless ``extend_scene_range`` is false.
    """
    scene = scene or bpy.context.scene
    plan = read_retarget(obj, source, method, scene, lam, key_tolerance, action_name, key_shape, key_pose_action,
                         extend_scene_range, bones)
    return write_retarget(compute_retarget(plan, progress), scene)


def retarget_dense(obj, source_obj, method: str = "spacetime", scene=None, lam: float = 1e-7,
                   key_tolerance: float = 0.0, action_name: str = None, key_shape: str = "BEZIER",
                   extend_scene_range: bool = True, progress=None) -> RetargetReport:
    """Retarget an animated mesh (any deformation) onto ``obj``'s sliders by geometric fitting (the scene
    range's frames; reading them is the first tenth of ``progress``)."""
    scene = scene or bpy.context.scene
    plan = read_retarget_dense(obj, source_obj, method, scene, lam, key_tolerance, action_name, key_shape,
                               extend_scene_range, scaled(progress, 0.0, 0.1))
    return write_retarget(compute_retarget(plan, scaled(progress, 0.1, 1.0)), scene)


def _settings(lam, key_tolerance, key_shape) -> tuple:
    """The retarget settings checked before any work: λ > 0 and the key tolerance ≥ 0, finite; the key shape."""
    choice(key_shape, "key shape", KEY_SHAPES, ErrorCode.KEY_SHAPE)
    return positive(lam, "lam"), non_negative(key_tolerance, "key tolerance")


def _plan_curves(names, paths, frames, W, key_tolerance: float, key_shape: str, progress=None) -> tuple:
    """Every curve to write, computed and checked before anything is written (no Blender data; any thread):
    ``([(data path, frames, values, slopes or None)], fraction of the keys kept)``; ``progress`` per curve."""
    choice(key_shape, "key shape", KEY_SHAPES, ErrorCode.KEY_SHAPE)
    plan, kept = [], 0
    # smooth keys: every curve reduced in one vectorised call (progress inside); linear keys: per curve
    reduced = (reduce_keys_bezier_curves(frames, W, key_tolerance, progress=progress)
               if key_tolerance > 0 and key_shape == "BEZIER" else None)
    for j, (name, path) in enumerate(zip(names, paths)):
        if key_tolerance <= 0:
            plan.append((path, frames, W[:, j], None))
        elif reduced is not None:
            idx, key_values, slopes = reduced[j]
            plan.append((path, frames[idx], key_values, slopes))
        else:
            idx = reduce_keys(frames, W[:, j], key_tolerance)
            plan.append((path, frames[idx], W[idx, j], None))
        kept += len(plan[-1][1])
        if not all(np.isfinite(a).all() for a in plan[-1][1:] if a is not None):
            raise ShapeSpaceError(f"the keys of {name!r} came out NaN or infinite; nothing was written",
                                  ErrorCode.NON_FINITE)
        if reduced is None:
            notify(progress, (j + 1) / max(len(names), 1))
    notify(progress, 1.0)
    return plan, kept / max(len(frames) * len(names), 1)


def _write_plan(key, plan) -> None:
    for path, x, y, slopes in plan:
        if slopes is None:
            actions.write_curve(key, path, x, y)
        else:
            actions.write_bezier_curve(key, path, x, y, slopes)


def _written_range(curves) -> tuple | None:
    """(first, last) frame keyed by the curves, or None when they key nothing."""
    firsts = [float(c[1][0]) for c in curves if len(c[1])]
    lasts = [float(c[1][-1]) for c in curves if len(c[1])]
    return (min(firsts), max(lasts)) if firsts else None


def _extend_scene(scene, first: float, last: float) -> bool:
    """Widen ``scene``'s frame range to include ``[first, last]`` (whole frames); whether it changed."""
    start, end = math.floor(first), math.ceil(last)
    changed = False
    if end > scene.frame_end:
        scene.frame_end = end
        changed = True
    if start < scene.frame_start:
        scene.frame_start = start
        changed = True
    return changed


def _write_result(obj, curves, action_name, report, scene, extend_scene_range: bool,
                  bones: tuple = (None, None)) -> RetargetReport:
    """Key the planned ``curves`` into a new action on ``obj``, widen the scene's frame range (when asked) and
    remember the report and the action it replaces (for Discard Result); ``bones = (armature, bone curves)``
    keys the head / eye bones in the same action set (:func:`_write_bones`).

    A failure while writing removes the new action(s) and gives the rig (and the armature) back the action
    (and slot) it played, so the file is as before.  The new action gets a fake user; the displaced one too
    (the report remembers whether it had one)."""
    key = obj.data.shape_keys
    ad = key.animation_data
    previous = ad.action if ad is not None else None
    previous_slot = getattr(ad, "action_slot", None) if ad is not None else None
    previous_fake = bool(previous.use_fake_user) if previous is not None else None
    written = _written_range(curves)
    if written is not None:
        report.frame_range = [int(v) if float(v).is_integer() else v for v in written]
    widen = bool(extend_scene_range and written is not None and scene is not None)
    report.scene_range_extended = widen and (math.floor(written[0]) < scene.frame_start
                                             or math.ceil(written[1]) > scene.frame_end)
    if report.scene_range_extended:
        report.scene_range_before = [scene.frame_start, scene.frame_end]
    action = None
    arm, bone_plan = bones
    arm_ad = arm.animation_data if arm is not None else None
    arm_before = (getattr(arm_ad, "action", None), getattr(arm_ad, "action_slot", None), arm_ad is not None)
    bones_action = None
    try:
        action = actions.new_action(key, action_name)
        _write_plan(key, curves)
        if bone_plan:
            bones_action = _write_bones(arm, action, bone_plan, report)
            report.armature = arm.name
            report.armature_previous = [arm_before[0].name if arm_before[0] is not None else "",
                                        getattr(arm_before[1], "identifier", "") or "",
                                        bool(arm_before[0].use_fake_user) if arm_before[0] is not None else False]
        report.action = action.name
        report.previous_action = previous.name if previous is not None else ""
        report.previous_fake_user = previous_fake
        data = {k: v for k, v in report.to_json().items() if k in REPORT_KEYS}
        storage.write_id_blob(key, LAST_PROP, LAST_SCHEMA, data)
    except BaseException:
        if arm is not None:
            _restore(arm, bones_action if bones_action is not action else None, *arm_before)
        _restore(key, action, previous, previous_slot, had_animation=ad is not None)
        raise
    action.use_fake_user = True               # every result survives saving (a batch keeps them all)
    if bones_action is not None:
        bones_action.use_fake_user = True
        if arm_before[0] is not None:
            arm_before[0].use_fake_user = True
    if previous is not None:
        previous.use_fake_user = True         # the displaced action too (Discard Result restores the flag)
    if widen:
        _extend_scene(scene, *written)
    return report


def _write_bones(arm, action, bone_plan: list, report) -> object:
    """Key the bones' planned curves on ``arm``: in the result ``action`` (a slot of its own, Blender 4.4+) or
    in a second action ``<action> bones`` (4.2: an action animates one kind of ID), as live takes are
    recorded; the armature plays it.  Returns the action the bones were keyed in."""
    target = action if actions.LAYERED else bpy.data.actions.new(action.name + " bones")
    if arm.animation_data is not None and actions.LAYERED:
        arm.animation_data.action = None                    # a fresh slot for the armature in the result
    actions.assign_action(arm, target)
    for path, index, bone, x, y, slopes in bone_plan:
        if slopes is None:
            actions.write_curve(arm, path, x, y, index=index, group=bone)
        else:
            actions.write_bezier_curve(arm, path, x, y, slopes, index=index, group=bone)
    report.bones = list(dict.fromkeys(b for _, _, b, *_ in bone_plan))
    report.bones_action = target.name
    return target


def _restore(key, made, previous, previous_slot, had_animation: bool) -> None:
    """Undo a half-written result: delete ``made``, give ``key`` back ``previous`` (and its slot)."""
    if made is not None and made.name in bpy.data.actions:
        bpy.data.actions.remove(made)
    if previous is not None:
        ad = key.animation_data or key.animation_data_create()
        ad.action = previous
        if previous_slot is not None and hasattr(ad, "action_slot"):
            ad.action_slot = previous_slot
    elif not had_animation and key.animation_data is not None:
        key.animation_data_clear()


def reduce_action_keys(obj, names, frames, W, tolerance: float, key_shape: str = "BEZIER") -> float:
    """Rewrite the dense curves ``W`` (f, n) of ``names`` with the fewest keys within ``tolerance``
    (smooth Bézier keys, or linear ones) in the action ``obj``'s Key plays; returns the fraction of keys kept.
    All keys are computed before the first curve is rewritten."""
    choice(key_shape, "key shape", KEY_SHAPES, ErrorCode.KEY_SHAPE)
    tolerance = positive(tolerance, "key tolerance")
    plan, kept = _plan_curves(names, [actions.shape_key_path(n) for n in names],
                              np.asarray(frames, dtype=np.float64), np.asarray(W, dtype=np.float64),
                              tolerance, key_shape)
    _write_plan(obj.data.shape_keys, plan)
    return kept


# ------------------------------------------------------------------ the last result (stored on the Key)
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


# ------------------------------------------------------------------ channel-mapping overrides (stored on the Key)
def stored_mapping(obj) -> dict:
    """The channel-mapping overrides stored on ``obj``'s shape keys: ``{source: {target, gain, offset}}``."""
    key = obj.data.shape_keys
    data = storage.read_id_blob(key, MAPPING_PROP, MAPPING_SCHEMA)
    data.pop("schema_version", None)
    for source, entry in data.items():
        bad = (not isinstance(entry.get("target"), str)
               or any(not isinstance(entry.get(k, 0.0), (int, float)) or isinstance(entry.get(k), bool)
                      for k in ("gain", "offset")))
        if bad:
            raise ShapeSpaceError(f"damaged ShapeSpace data in {storage.where(key, MAPPING_PROP)}: entry "
                                  f"'{source}' needs a target name and numeric gain and offset",
                                  ErrorCode.CORRUPT_METADATA)
    return data


def _mapping_number(source: str, label: str, value) -> float:
    """A gain or offset: finite and within ±:data:`MAX_MAPPING_VALUE` (slider ranges lie within ±10)."""
    value = float(value)
    if not math.isfinite(value):
        raise ShapeSpaceError(f"the {label} of {source!r} must be a finite number, got {value:g}",
                              ErrorCode.NON_FINITE)
    if abs(value) > MAX_MAPPING_VALUE:
        raise ShapeSpaceError(f"the {label} of {source!r} must lie within ±{MAX_MAPPING_VALUE:g}, got {value:g}",
                              ErrorCode.RANGE)
    return value


def remove_mapping(obj, source: str) -> None:
    """Drop the override of ``source`` (name matching applies again)."""
    data = stored_mapping(obj)
    if source not in data:
        raise ShapeSpaceError(f"{obj.name!r} has no mapping override for {source!r}", "missing_channel")
    del data[source]
    storage.write_id_blob(obj.data.shape_keys, MAPPING_PROP, MAPPING_SCHEMA, data)


def set_mapping(obj, source: str, target: str, gain: float = 1.0, offset: float = 0.0) -> None:
    """Store a channel mapping override (kept in the .blend on the shape-key datablock)."""
    key = obj.data.shape_keys
    if not source:
        raise ShapeSpaceError("name the source channel", "missing_channel")
    gain, offset = _mapping_number(source, "gain", gain), _mapping_number(source, "offset", offset)
    if key is None or target not in key.key_blocks or target == key.reference_key.name:
        raise ShapeSpaceError(f"{obj.name!r} has no shape key {target!r} to map to", "missing_key")
    data = stored_mapping(obj)
    data[source] = {"target": target, "gain": float(gain), "offset": float(offset)}
    storage.write_id_blob(key, MAPPING_PROP, MAPPING_SCHEMA, data)


# ------------------------------------------------------------------ dense performances (mesh sequences)
def _group_vertices(obj, name):
    from .meshes import group_weight_vector
    w = group_weight_vector(obj, name)
    return np.flatnonzero(w > 0) if w is not None else np.zeros(0, dtype=int)


def landmark_pairs(source, target):
    """Corresponding vertices from vertex groups named ``lm_<name>`` on both meshes (one vertex each)."""
    names = sorted(g.name for g in source.vertex_groups if g.name.startswith(LANDMARK_PREFIX)
                   and g.name in target.vertex_groups)
    src, dst = [], []
    for n in names:
        a, b = _group_vertices(source, n), _group_vertices(target, n)
        if a.size and b.size:
            src.append(int(a[0]))
            dst.append(int(b[0]))
    return np.array(src, dtype=int), np.array(dst, dtype=int)


def mesh_sequence(source, scene, frames, progress=None) -> np.ndarray:
    """Evaluated (object-space) positions of ``source`` at each frame, (f, p, 3); ``progress`` per frame.
    The scene gets its current frame back however this ends."""
    from .meshes import evaluated_positions
    current = scene.frame_current
    depsgraph = bpy.context.evaluated_depsgraph_get()
    out = []
    try:
        for k, f in enumerate(frames, start=1):
            scene.frame_set(int(f))
            out.append(evaluated_positions(source, depsgraph).astype(np.float64))
            notify(progress, k / len(frames))
    finally:
        scene.frame_set(current)
    return np.stack(out)


def _dense_inputs(source, target_model, target, scene, frames, progress=None) -> dict:
    """What :func:`core.retarget.transfer_motion` needs, read from Blender: the source's evaluated mesh at every
    frame, its neutral (reference shape key, else its mesh vertices — for a cache, as imported), its ``stable``
    group (head motion removed per frame) and the ``lm_*`` landmark pairs; checked before any work."""
    from .arrays import read_float
    from .meshes import evaluated_positions, vertex_positions
    src_lm, dst_lm = landmark_pairs(source, target)
    n_source = len(evaluated_positions(source, bpy.context.evaluated_depsgraph_get()))   # before a long read
    same_topology = n_source == target_model.neutral.shape[0] and not src_lm.size
    if not same_topology and src_lm.size < 3:
        raise ShapeSpaceError(f"different meshes need at least 3 landmark pairs (vertex groups named "
                              f"'{LANDMARK_PREFIX}…' on both); found {src_lm.size}", "too_few_landmarks")
    key = source.data.shape_keys
    rest = (read_float(key.reference_key.data, "co", 3) if key is not None else
            vertex_positions(source.data)).astype(np.float64)
    seq = mesh_sequence(source, scene, frames, progress)
    return {"seq": seq, "rest": rest, "stable": _group_vertices(source, STABLE_GROUP), "src_lm": src_lm,
            "dst_lm": dst_lm}


def _dense_positions(inputs: dict, target_model) -> np.ndarray:
    """The read performance transferred onto the target's vertices, (f, p_t·3) (no Blender data)."""
    seq = inputs["seq"]
    stabilise(seq, inputs["rest"], inputs["stable"])
    src_lm, dst_lm = inputs["src_lm"], inputs["dst_lm"]
    same_topology = seq.shape[1] == target_model.neutral.shape[0] and not src_lm.size
    if not same_topology and src_lm.size < 3:
        raise ShapeSpaceError(f"different meshes need at least 3 landmark pairs (vertex groups named "
                              f"'{LANDMARK_PREFIX}…' on both); found {src_lm.size}", "too_few_landmarks")
    return transfer_motion(seq, inputs["rest"], target_model.neutral, target_model.deltas, target_model.scale,
                           src_lm, dst_lm)


def dense_source_positions(source, target_model, target, scene, frames):
    """The source performance transferred onto the target's vertices: (f, p_t·3) positions
    (:func:`_dense_inputs` then :func:`core.retarget.transfer_motion`: vertex to vertex for the same topology,
    else landmark warp and closest points)."""
    return _dense_positions(_dense_inputs(source, target_model, target, scene, frames), target_model)


# ------------------------------------------------------------------ landmarks
def add_landmark(obj, name: str, vertex: int) -> str:
    """(Re)define the landmark vertex group ``lm_<name>`` as the single vertex ``vertex``."""
    group_name = name if name.startswith(LANDMARK_PREFIX) else LANDMARK_PREFIX + name
    group = obj.vertex_groups.get(group_name) or obj.vertex_groups.new(name=group_name)
    group.remove(list(range(len(obj.data.vertices))))
    group.add([int(vertex)], 1.0, "REPLACE")
    return group.name


def landmarks_from_shapes(source, target) -> list:
    """Create landmark pairs from the shapes both meshes share (by mapped name): each pair's vertices are
    the ones that shape moves most on each mesh (chin for jawOpen, lids for eyeBlink, …).  Existing
    ``lm_auto_*`` groups are replaced; hand-placed landmarks are kept.  Returns the group names."""
    for ob in (source, target):
        if ob.type != "MESH" or ob.data.shape_keys is None or len(ob.data.shape_keys.key_blocks) < 2:
            raise ShapeSpaceError(f"{ob.name!r} has no shape keys to find landmarks from", "no_shape_keys")
    model_s = shapekeys.read_blendshape_model(source)
    model_t = shapekeys.read_blendshape_model(target)
    mapping = channel_mapping(target, model_s.names, model_t.names)
    src, dst, used = peak_landmarks(model_s.deltas, model_t.deltas, [(i, j) for i, j, _, _ in mapping])
    if src.size < 3:
        raise ShapeSpaceError(f"only {src.size} shared shapes have a clear peak vertex; place landmarks by hand",
                              "too_few_landmarks")
    for ob in (source, target):
        for group in [g for g in ob.vertex_groups if g.name.startswith(LANDMARK_PREFIX + "auto_")]:
            ob.vertex_groups.remove(group)
    names = []
    for a, b, (_, j) in zip(src, dst, used):
        name = "auto_" + model_t.names[j]
        add_landmark(source, name, int(a))
        names.append(add_landmark(target, name, int(b)))
    return names


def selected_vertex(obj):
    """The single selected vertex of a mesh (object mode data), or None."""
    sel = np.zeros(len(obj.data.vertices), dtype=bool)
    obj.data.vertices.foreach_get("select", sel)
    idx = np.flatnonzero(sel)
    return int(idx[0]) if idx.size == 1 else None
