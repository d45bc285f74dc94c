"""Retargeting onto a shape-key rig: read the plan from Blender, write the result back (thesis 3.5, ch. 5).

Three steps, so a modal operator can run the middle one in a worker thread (:class:`core.jobs.BackgroundJob`):
:func:`read_retarget` / :func:`read_retarget_dense` (main thread: everything from Blender, a
:class:`~core.retarget.job.RetargetPlan`) → :func:`core.retarget.job.compute_retarget` (pure numerics, no
Blender data, progress + Cancelled) → :func:`write_retarget` (main thread: one step, nothing written before it).
:func:`retarget` and :func:`retarget_dense` run the three in a row; :func:`start_retarget_job` and
:func:`finish_retarget_job` run the middle one in a worker thread.

Nothing is lost: everything is validated and computed (keys included, checked finite) before the first write,
and a failure while writing removes the new action and gives the rig back what it played.  Every result action
has a fake user (a batch of results all survive saving), and the action a result displaces gets one too
(whether it had one is remembered; *Discard Result* restores it).
"""
from __future__ import annotations

import math

import bpy
import numpy as np

from ...core.errors import ErrorCode
from ...core.jobs import BackgroundJob
from ...core.progress import scaled
from ...core.result import Issue, ShapeSpaceError
from ...core.retarget import GEOMETRIC_METHODS, METHODS, RetargetReport, split_mapping
from ...core.retarget.job import (
    KEY_SHAPES,
    RetargetOutcome,
    RetargetPlan,
    check_settings,
    compute_retarget,
    plan_curves,
    written_range,
)
from ...core.retarget.performance import check_dense_budget
from ...core.validate import choice, positive
from .. import actions, shapekeys, storage
from .dense import read_dense_inputs
from .last_result import LAST_PROP, LAST_SCHEMA, REPORT_KEYS
from .mapping import resolve_mapping
from .sources import HeadEyeBones, is_capture_file, read_capture_source, read_head_eye_bones, read_learned, read_source

__all__ = ["NONLINEAR_MESSAGE", "read_retarget", "read_retarget_dense", "write_retarget", "start_retarget_job",
           "finish_retarget_job", "retarget", "retarget_dense", "reduce_action_keys"]

NONLINEAR_MESSAGE = ("the target has in-between or combination shapes, so its face is not linear in the sliders: "
                     "fit methods cannot use it; retarget with copy or learned (the driven shapes follow)")


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
    lam, key_tolerance = check_settings(lam, key_tolerance, key_shape)
    scene = scene or bpy.context.scene
    model = shapekeys.read_blendshape_model(obj)
    if not model.is_linear and method in GEOMETRIC_METHODS:
        raise ShapeSpaceError(NONLINEAR_MESSAGE, "nonlinear")
    rotations = None
    if is_capture_file(source):
        names, frames, src, issues, rotations, _ = read_capture_source(source, scene)
    else:
        names, frames, src, issues = read_source(source, scene)
    report = RetargetReport(source=str(source), method=method, frames=int(frames.size), issues=list(issues))
    plan = RetargetPlan(obj.name, method, lam, key_tolerance, key_shape, action_name or f"{obj.name}_{method}",
                        bool(extend_scene_range), model, [actions.shape_key_path(n) for n in model.names],
                        np.asarray(frames, dtype=np.float64), report, _rig_signature(obj))
    plan.bones, plan.rotations, plan.armature = read_head_eye_bones(bones, frames, rotations, report)
    plan.bone_paths = _bone_paths(plan.bones)
    plan.mirror = bool(bones is not None and bones.mirror)
    if method == "learned":     # the artist's key poses define the map: no channel names needed
        learned = read_learned(obj, model, frames, src, key_pose_action)
        plan.raw = learned.weights                                                # unbounded ideal
        report.key_poses, report.learned_fit_rms = learned.key_poses, learned.fit_rms
        report.mapped_channels = learned.mapped_channels
    else:
        mapping, warnings = resolve_mapping(obj, names, model.names)
        report.issues += [Issue("warning", "stale_mapping", w) for w in warnings]
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
    lam, key_tolerance = check_settings(lam, key_tolerance, key_shape)
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
    plan.dense = read_dense_inputs(source_obj, model, obj, scene, frames, progress)
    return plan


def _bone_paths(bones: list) -> list | None:
    """Each head / eye bone curve's ``(data path, array index, bone name)``, in the order of
    :func:`core.headpose.bone_curves`' columns (:attr:`core.retarget.job.RetargetPlan.bone_paths`)."""
    if not bones:
        return None
    return [(actions.bone_path(b.name, b.channel[0]), i, b.name) for b in bones for i in range(b.channel[1])]


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


def _write_plan(key, plan) -> None:
    for path, x, y, slopes in plan:
        if slopes is None:
            actions.write_curve(key, path, x, y)
        else:
            actions.write_bezier_curve(key, path, x, y, slopes)


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
    written = written_range(curves)
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
    plan, kept = plan_curves(names, [actions.shape_key_path(n) for n in names],
                              np.asarray(frames, dtype=np.float64), np.asarray(W, dtype=np.float64),
                              tolerance, key_shape)
    _write_plan(obj.data.shape_keys, plan)
    return kept
