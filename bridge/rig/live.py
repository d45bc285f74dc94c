"""Live capture solved onto any rig's stored controls (issue #25, item 4): the Blender side of the live route.

When the live target (a face mesh) has a stored control set (:mod:`bridge.rig.stored`) and the method is
``CONTROLS``, :func:`build_rig_pipeline` replaces the slider pipeline of :mod:`bridge.live.rig` by a
:class:`RigLivePipeline` with the same interface (``process`` / ``calibrate_to`` / ``solve`` / ``write``, the
session's timer does not know the difference):

- at Start (before the port opens): the control set is read from the rig as it is now; a
  :class:`~bridge.rig.evaluate.RigEvaluator` is opened on a deterministic vertex sample
  (:func:`bridge.rig.capture.sample_vertices`) with every refusal of the offline route (Edit Mode, linked data,
  locked, inert or held channels, invalid drivers, a rig that does not evaluate the same twice), plus a
  datablock owning controls that plays an action (the action would overwrite every streamed value); the
  source's channels are mapped onto the face's own shape keys exactly as the offline capture route maps them
  (:func:`bridge.retarget.mapping.resolve_mapping`, gain, offset, slider ranges), the keys' world-space basis and
  deltas at the sample are read once (thesis Eq. 3.1), the Jacobian at the current controls is computed once,
  and the per-frame budget of rig evaluations is fixed from the rig's measured evaluation time
  (:data:`LIVE_EVAL_MS`, at most :data:`MAX_BUDGET`): a rig whose evaluation costs about a millisecond or more
  (Rigify's face) gets one verified step per packet;
- per frame: weights → target points through the face's keys → one budgeted, warm-started bounded step in
  control space (:class:`core.rig.live.LiveRigSolver`: every trial verified by Blender's evaluation; each
  evaluation writes only the channels that changed) → the controls written on the rig → the viewport's own
  evaluation draws them.  The frame's last evaluation is what the rig shows: when it is the accepted trial the
  viewport's evaluation has nothing left to do; when it is a Jacobian column refresh (a probe moved by a tenth of
  the offline finite-difference step, :data:`LIVE_REFRESH_STEP`) or a refused trial, the verified controls are
  written back — one more evaluation — only when the shown surface is farther from the frame's targets than the
  verified one by more than :data:`LIVE_SHOW_TOL_REL` of the diagonal (``redisplays`` counts them).  So a
  packet costs the budget's evaluations and at most one more, and on a one-evaluation budget usually exactly one:
  the same as a shape-key face's packet (write, then the viewport's evaluation).  A frame that runs out of budget
  is counted (:attr:`RigLivePipeline.budget_hits`, shown by the Live panel) — never silent.  Stop and Stop
  Recording write the last verified controls once (:meth:`RigLivePipeline.settle`): the stream never leaves a
  probe or a refused trial on the rig.

Recording (:class:`RigTakeRecorder`) keys the control channels (a bone in ``QUATERNION`` / ``AXIS_ANGLE`` mode
on all four components) and the head / eye bones, one LINEAR key per scene frame, in one new action per
datablock (fake user, not assigned while recording: the take so far is always in the file); Stop Recording makes
the rig play them.  These are the rig's own actions, not live-take actions of the shape-key route (the Takes
list, whose Play and clean-up passes act on sliders, does not list them).
"""
from __future__ import annotations

import time
from collections import deque
from dataclasses import replace

import bpy
import numpy as np

from ...core.blas_threads import single_threaded
from ...core.errors import ErrorCode
from ...core.headpose import bone_values
from ...core.live import FACECAP_52, LLF_BLENDSHAPES, CalibratedInput, OneEuroFilter
from ...core.result import ShapeSpaceError
from ...core.retarget import split_mapping
from ...core.rig import ChannelKind, LiveRigSolver, quaternion_from_rotation_vector, ridge_unit
from .. import actions
from ..retarget import bone_specs, write_pose_bones
from ..retarget.mapping import resolve_mapping
from . import stored
from .capture import sample_vertices
from .channels import EULER_MODES, Binding
from .evaluate import RigEvaluator
from .take import _animated, rest_controls, shape_key_targets

__all__ = ["LIVE_EVAL_MS", "LIVE_REFRESH_STEP", "LIVE_SHOW_TOL_REL", "MAX_BUDGET", "METHOD", "RigLivePipeline",
           "RigTakeRecorder", "build_rig_pipeline", "has_controls"]

#: The live method that solves onto a stored control set.
METHOD = "CONTROLS"
#: Rig evaluations per frame are fixed at Start so that they take about this long at the rig's median evaluation
#: time (at least one).  Small on purpose: a depsgraph evaluation's tail is several times its median
#: (multithreaded evaluation waking idle cores; on the benchmark VM Rigify's face: 1.8 ms median, 11 ms p99), so
#: only a rig that evaluates in well under a millisecond affords several evaluations in a 16.7 ms frame.
LIVE_EVAL_MS = 1.5
#: At most this many rig evaluations per frame (at least one).
MAX_BUDGET = 6
#: Ridge toward the rest controls (as the offline capture route, :func:`bridge.rig.capture.retarget_capture_onto_rig`).
REG = 1e-6
#: Stopping distances of a live frame, as fractions of the evaluated diagonal: every pin within ``LIVE_PIN_TOL_REL``,
#: or the Gauss–Newton step moving no pin by more than ``LIVE_XTOL_REL`` (a tenth of the 1e-3 recovery goal, 0.03 mm
#: on a 30 cm head, as a drag's mouse move, :data:`bridge.rig.drag.DRAG_XTOL_REL`: the next frame goes on from there;
#: the offline take goes on to 1e-6).
LIVE_PIN_TOL_REL, LIVE_XTOL_REL = 1e-5, 1e-4
#: The rig may go on showing a frame's last evaluation (a refused trial or a column-refresh probe) instead of its
#: verified controls when no pin is farther from the targets than the verified surface's farthest pin plus this
#: fraction of the diagonal (a tenth of the 1e-3 recovery goal); otherwise the verified controls are written back.
LIVE_SHOW_TOL_REL = 1e-4
#: Column refreshes of a live stream step by this fraction of the offline finite-difference steps (the surface
#: moves by about 1e-4 of the diagonal, within :data:`LIVE_SHOW_TOL_REL`: a probe the rig shows is invisible).
LIVE_REFRESH_STEP = 0.1
_SOURCE_NAMES = {"LLF": LLF_BLENDSHAPES, "FACECAP": FACECAP_52, "IFACIALMOCAP": FACECAP_52}
_TIMINGS = 600


def has_controls(obj) -> bool:
    """Whether ``obj`` is a face with enabled stored control channels (the live panel then offers the method)."""
    if obj is None or obj.type != "MESH":
        return False
    try:
        return any(e.enabled for e in stored.read(obj)[1])
    except ShapeSpaceError:
        return False


def _refuse_playing(bindings) -> None:
    for b in bindings:
        idb = _animated(b)[0]
        action = actions.active_action(idb)
        if action is not None:
            raise ShapeSpaceError(f"{idb.name!r} plays the action {action.name!r}, which would overwrite the "
                                  f"streamed {b.channel.name!r}: unassign it first", ErrorCode.INVALID)


class _Targets:
    """Source weights → world-space target points at the sample (the face's own keys, the offline mapping)."""

    def __init__(self, mesh_obj, names, idx):
        key = mesh_obj.data.shape_keys
        if key is None or not key.use_relative or len(key.key_blocks) < 2:
            raise ShapeSpaceError(f"{mesh_obj.name!r} has no relative shape keys to play the capture's weights on",
                                  ErrorCode.NO_SHAPE_KEYS)
        keys = [kb.name for kb in key.key_blocks if kb != key.reference_key]
        mapping, _ = resolve_mapping(mesh_obj, list(names), keys)
        if not mapping:
            raise ShapeSpaceError(f"{mesh_obj.name!r} has no shape key matching the source's channels: the face "
                                  "needs the source's shape keys (ARKit names) to evaluate it", ErrorCode.NO_MAPPING)
        pairs, gain, offset = split_mapping(mapping, len(keys))
        last = {j: i for i, j in pairs}                           # as copy_weights: a later pair wins
        self.cols = sorted(last)
        self.src = np.array([last[j] for j in self.cols], dtype=np.int64)
        self.gain, self.offset = gain[self.cols], offset[self.cols]
        self.lo = np.array([key.key_blocks[keys[j]].slider_min for j in self.cols])
        self.hi = np.array([key.key_blocks[keys[j]].slider_max for j in self.cols])
        used = [keys[j] for j in self.cols]
        rows = shape_key_targets(mesh_obj, used, np.vstack([np.zeros(len(used)), np.eye(len(used))]), idx)
        self.base = rows[0]
        self.deltas = (rows[1:] - rows[0]).reshape(len(used), -1)             # (k, 3p)

    def __call__(self, weights) -> np.ndarray:
        """Target points (p, 3) of source weights (n_source,): :func:`core.retarget.copy_weights` (gain, offset,
        slider ranges) on the mapped keys, then the keys' model."""
        w = np.clip(self.gain * np.asarray(weights, np.float64)[self.src] + self.offset, self.lo, self.hi)
        return self.base + (w @ self.deltas).reshape(self.base.shape)


class RigLivePipeline(CalibratedInput):
    """What one live frame goes through onto a rig's controls (module doc).

    Unlike the slider pipeline it keeps the open evaluator (its channel bindings) between frames: every frame
    first checks, by name and datablock address, that the face and the rig's objects are still the ones bound
    (deleted, or replaced by an undo: the session stops with that message rather than touch a stale datablock).
    The evaluator is never restored: when the session stops the last verified controls stay (:meth:`settle`), as
    the streamed weights stay on the sliders."""

    method = METHOD

    def __init__(self, target: str, ev: RigEvaluator, targets: _Targets, solver: LiveRigSolver, n_source: int,
                 armature: str, bones: list, mirror: bool, smoothing):
        self.target, self.ev, self.targets, self.solver = target, ev, targets, solver
        self.n_source, self.armature, self.bones, self.mirror = n_source, armature, bones, mirror
        self.smoothing, self.neutral = smoothing, None
        self.controls = ev.controls
        self.owners = {b.object.name: b.object.as_pointer() for b in ev.bindings}
        self.owners[target] = ev.mesh_obj.as_pointer()
        self.slider_names = []
        self.frames = self.budget_hits = self.redisplays = 0
        self.evaluations = deque(maxlen=_TIMINGS)
        self.last = None
        self.shown = np.array(solver.c)        # the controls written on the rig (build_rig_pipeline evaluated them)
        self.writer = _Writer(ev.bindings)
        self.show_tol = LIVE_SHOW_TOL_REL * ev.diagonal

    @property
    def budget(self) -> int:
        return self.solver.budget

    def _alive(self) -> str:
        for name, pointer in self.owners.items():
            ob = bpy.data.objects.get(name)
            what = "target" if name == self.target else "rig"
            if ob is None:
                return f"the {what} {name!r} was deleted"
            if ob.as_pointer() != pointer:
                return f"the {what} {name!r} was replaced (undo?): press Start again"
        return ""

    def solve(self, vector: np.ndarray) -> tuple:
        """Controls (n,) and ``{bone: values}`` for a processed vector: one budgeted step, evaluated on the rig."""
        why = self._alive()
        if why:
            raise ShapeSpaceError(why, ErrorCode.MISSING_TARGET)
        n = self.n_source
        t = self.targets(vector[:n])
        with single_threaded():              # small dense products: BLAS threads would only spin (core.blas_threads)
            frame = self.solver.step(self._evaluate, t)
        self.frames += 1
        self.budget_hits += int(frame.budget_hit)
        self.evaluations.append(frame.evaluations)
        self.last = frame
        if frame.last_evaluated is not None and not np.array_equal(frame.last_evaluated, frame.value):
            shown = np.linalg.norm(frame.last_points - t, axis=1).max()
            if shown > frame.pin_errors.max() + self.show_tol:
                self._set(frame.value)                    # the rig shows the accepted controls (module doc)
                self.redisplays += 1                      # … which the viewport's evaluation then draws
        return frame.value, bone_values(vector[n:n + 9], self.bones, self.mirror)

    def _set(self, c) -> None:
        """Write the channels of ``c`` (n,) that differ from what the rig shows (no depsgraph update)."""
        c = np.asarray(c, dtype=np.float64)
        self.writer(c, c != self.shown)
        self.shown = c.copy()

    def _evaluate(self, c) -> np.ndarray:
        """The rig's points at ``c``: the changed channels written, one depsgraph update, the sample read."""
        self._set(c)
        return self.ev.evaluate(None)

    def write(self, controls: np.ndarray, bones: dict) -> str:
        """Controls onto the rig (unless it shows them already) and the head / eye bones; '' or why not."""
        why = self._alive()
        if why:
            return why
        if self.last is None or not np.array_equal(controls, self.last.value):
            self._set(controls)
        if bones:
            return write_pose_bones(self.armature, self.bones, bones)
        return ""

    def settle(self) -> None:
        """Write the last verified controls onto the rig (Stop, Stop Recording): a frame may leave the rig showing
        its column-refresh probe or refused trial (within :data:`LIVE_SHOW_TOL_REL`, module doc), which must not be
        the pose the stream leaves behind.  Only the channels that differ are written (nothing when the rig shows
        them already); nothing when the rig's objects are gone."""
        if not self._alive():
            self._set(self.solver.c)

    @property
    def stats(self) -> dict:
        """Counters: frames, budget hits, frames whose written controls the viewport had to evaluate again
        (``redisplays``: the last evaluation was a refused trial or a column refresh), mean evaluations."""
        return {"frames": self.frames, "budget_hits": self.budget_hits, "redisplays": self.redisplays,
                "evaluations_mean": float(np.mean(self.evaluations)) if self.evaluations else 0.0}

    def counters(self) -> str:
        """One line for the Live panel: budget, evaluations per frame, frames that ran out of budget."""
        ev = float(np.mean(self.evaluations)) if self.evaluations else 0.0
        return (f"{len(self.controls)} controls · budget {self.budget} evaluations/frame · {ev:.1f} used · "
                f"{self.budget_hits} of {self.frames} frames hit the budget")

    def take_recorder(self, pipeline, name: str, meta: dict):
        return RigTakeRecorder(pipeline, name, meta)


class _Writer:
    """Writes the changed channels of a control vector: a bone's location, scale or Euler rotation in one
    assignment of the vector (one RNA update per bone, not one per component), every other channel (a quaternion or
    axis-angle rotation component, a property, a slider) by its binding."""

    def __init__(self, bindings):
        groups = {}
        self.singles = []
        for i, b in enumerate(bindings):
            ch = b.channel
            vector = ch.kind != ChannelKind.ROTATION or ch.rotation_mode in EULER_MODES
            if b.prop is None and ch.index >= 0 and vector:
                groups.setdefault((b.target.as_pointer(), b.attr), []).append(i)
            else:
                self.singles.append((i, b))
        self.groups = [(bindings[cols[0]].target, bindings[cols[0]].attr, np.array(cols),
                        [bindings[i].channel.index for i in cols]) for cols in groups.values()]

    def __call__(self, c: np.ndarray, changed: np.ndarray) -> None:
        for target, attr, cols, comps in self.groups:
            if changed[cols].any():
                vec = list(getattr(target, attr))
                for k, v in zip(comps, c[cols].tolist()):
                    vec[k] = v
                setattr(target, attr, vec)
        for i, b in self.singles:
            if changed[i]:
                b.set(c[i])


def _budget(ev: RigEvaluator, c0) -> int:
    """Evaluations per frame so they take about :data:`LIVE_EVAL_MS` (median of a few timed evaluations)."""
    times = []
    c = np.array(c0, dtype=np.float64)
    for k in range(4):
        x = c.copy()
        i = k % c.size
        x[i] += ev.steps[i] if x[i] + ev.steps[i] <= ev.controls.hi[i] else -ev.steps[i]
        t0 = time.perf_counter()
        ev.evaluate(x if k % 2 == 0 else c)
        times.append(time.perf_counter() - t0)
    ms = max(float(np.median(times)) * 1e3, 1e-3)
    return int(np.clip(LIVE_EVAL_MS // ms, 1, MAX_BUDGET))


def build_rig_pipeline(scene, settings, target, budget: int | None = None) -> RigLivePipeline:
    """Validate and precompute everything a live frame onto ``target``'s stored controls needs (module doc).

    Parameters
    ----------
    scene : bpy.types.Scene
    settings : the scene's ``shapespace_live`` settings (source, smoothing, head / eye bones)
    target : bpy.types.Object
        The face mesh with a stored control set.
    budget : int, optional
        Rig evaluations per frame (default: from the rig's measured evaluation time).
    """
    if target is None or target.type != "MESH":
        raise ShapeSpaceError(f"the live target {getattr(target, 'name', target)!r} is not a face mesh",
                              ErrorCode.NOT_MESH)
    controls = stored.control_set(target)
    names = _SOURCE_NAMES[settings.source]
    key = target.data.shape_keys
    keys = [kb.name for kb in key.key_blocks[1:]] if key is not None else []
    idx = sample_vertices(target, keys) if keys else np.arange(0)
    targets = _Targets(target, names, idx)
    arm, bones = ("", []) if settings.armature is None else (settings.armature.name, bone_specs(
        settings.armature, settings.head_bone, settings.neck_bone, settings.eye_left_bone, settings.eye_right_bone,
        settings.neck_share))
    ev = RigEvaluator(target, controls, idx, check=False)
    _refuse_playing(ev.bindings)
    try:
        ev.check()
        c0 = ev.c0.copy()
        lo, hi = ev.controls.solve_bounds(c0)
        n_budget = _budget(ev, c0) if budget is None else int(budget)
        P0 = ev.evaluate(c0)
        J0 = ev.jacobian(c0)
        ev.evaluate(c0)
    except BaseException:
        ev.restore()
        raise
    s, d = ev.controls.scale, ev.diagonal
    solver = LiveRigSolver(c0, P0, J0, lo=lo, hi=hi, scale=s, steps=LIVE_REFRESH_STEP * ev.steps,
                           rest=np.clip(rest_controls(controls), lo, hi), mu=REG * ridge_unit(J0, s),
                           pin_tol=LIVE_PIN_TOL_REL * d, xtol=LIVE_XTOL_REL * d, budget=n_budget)
    smoothing = OneEuroFilter(settings.min_cutoff, settings.beta) if settings.smoothing else None
    return RigLivePipeline(target.name, ev, targets, solver, len(names), arm, bones, bool(settings.mirror), smoothing)


# -- recording ----------------------------------------------------------------------------------------------------

def _curve_specs(pipeline: RigLivePipeline) -> list:
    """``[(datablock, data path, index, group, getter)]``: one per curve; the getter maps (controls, bones) to
    its value."""
    specs, done = [], set()
    for j, b in enumerate(pipeline.ev.bindings):
        ch = b.channel
        idb, path = _animated(b)
        group = path.split('"')[1] if path.startswith("pose.bones[") else ""
        if ch.kind == ChannelKind.ROTATION and ch.rotation_mode not in EULER_MODES:
            if (idb.as_pointer(), path) in done:
                continue
            done.add((idb.as_pointer(), path))
            cols = {pipeline.ev.bindings[i].channel.index: i for i, o in enumerate(pipeline.ev.bindings)
                    if _animated(o)[1] == path and _animated(o)[0] is idb}
            fixed = [Binding(replace(ch, index=k)).get() for k in range(3)]
            for k in range(4):
                specs.append((idb, path, k, group, _quat_getter(cols, fixed, ch.rotation_mode, k)))
            continue
        specs.append((idb, path, max(ch.index, 0), group, lambda c, _b, j=j: float(c[j])))
    arm = bpy.data.objects.get(pipeline.armature) if pipeline.armature else None
    for bone in pipeline.bones if arm is not None else ():
        path = actions.bone_path(bone.name, bone.channel[0])
        for k in range(bone.channel[1]):
            specs.append((arm, path, k, "Live", lambda _c, bv, n=bone.name, k=k: float(bv[n][k])))
    return specs


def _quat_getter(cols: dict, fixed: list, mode: str, k: int):
    def get(c, _bones):
        v = np.array([c[cols[a]] if a in cols else fixed[a] for a in range(3)])
        if mode == "QUATERNION":
            return float(quaternion_from_rotation_vector(v)[k])
        angle = float(np.linalg.norm(v))
        axis = v / angle if angle > 1e-12 else np.array([0.0, 1.0, 0.0])
        return float(np.r_[angle, axis][k])
    return get


class RigTakeRecorder:
    """Appends solved live frames to new actions on the rig's datablocks (module doc); the session's recorder
    interface (``action``, ``frames``, ``meta``, ``add``, ``finish``)."""

    def __init__(self, pipeline: RigLivePipeline, name: str, meta: dict) -> None:
        self.pipeline = pipeline
        self.specs = _curve_specs(pipeline)
        ids = []
        for s in self.specs:
            if all(s[0] is not o for o in ids):
                ids.append(s[0])
        self.entries = []                      # (kind, datablock name, action name)
        for idb in ids:
            action = bpy.data.actions.new(name if not self.entries else f"{name} {idb.name}")
            action.use_fake_user = True
            previous = actions.active_action(idb)
            actions.assign_action(idb, action)
            for owner, path, index, group, _ in self.specs:
                if owner is idb:
                    actions.ensure_fcurve(idb, path, index, group)
            if previous is not None:
                actions.assign_action(idb, previous)
            else:
                idb.animation_data.action = None
            self.entries.append(("KEY" if isinstance(idb, bpy.types.Key) else "OBJECT", idb.name, action.name))
        self.action = self.entries[0][2]
        self.frames = 0
        self.meta = dict(meta, frames=0, complete=False, armature=pipeline.armature,
                         actions=[e[2] for e in self.entries])

    def _curves(self) -> list:
        out = []
        for kind, id_name, action_name in self.entries:
            coll = bpy.data.shape_keys if kind == "KEY" else bpy.data.objects
            idb, action = coll.get(id_name), bpy.data.actions.get(action_name)
            if idb is None or action is None:
                return []
            by_path = {(fc.data_path, fc.array_index): fc for fc in actions.fcurves(action, idb)}
            out += [by_path.get((path, index)) for owner, path, index, _, _ in self.specs if owner.name == id_name]
        return out

    def add(self, samples: list) -> str:
        """Append ``[(scene frame, controls (n,), {bone: values})]``; returns '' or why recording must stop."""
        if not samples:
            return ""
        curves = self._curves()
        if len(curves) != len(self.specs) or any(fc is None for fc in curves):
            return f"the take {self.action!r} or its rig changed (undo?); recording stopped"
        values = [[spec[4](c, bones) for spec in self.specs] for _, c, bones in samples]
        for (frame, _, _), row in zip(samples, values):
            for fc, v in zip(curves, row):
                pts = fc.keyframe_points
                pts.add(1)
                kp = pts[-1]
                kp.co = kp.handle_left = kp.handle_right = (frame, v)
                kp.interpolation = "LINEAR"
        self.frames += len(samples)
        return ""

    def finish(self, complete: bool = True, play: bool = True) -> str:
        """Store the final metadata and (``play``: Stop Recording, Stop) write the last verified controls on the rig
        (:meth:`RigLivePipeline.settle`) and make the rig's datablocks play the take; returns its name."""
        if play:
            self.pipeline.settle()
        if bpy.data.actions.get(self.action) is None:
            return ""
        for fc in self._curves():
            if fc is not None:
                fc.update()
        self.meta.update(frames=self.frames, complete=complete)
        if play:
            for kind, id_name, action_name in self.entries:
                coll = bpy.data.shape_keys if kind == "KEY" else bpy.data.objects
                idb, action = coll.get(id_name), bpy.data.actions.get(action_name)
                if idb is not None and action is not None:
                    actions.assign_action(idb, action)
        return self.action

