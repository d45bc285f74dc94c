"""Retarget: read (main thread) → compute (a worker thread when invoked from the UI) → write (main thread).

From the UI (``invoke``) the computation runs in a :class:`core.jobs.BackgroundJob` while a modal timer shows
window-manager progress and a status-bar line; Esc cancels it and nothing is written.  Scripts, redo and
``EXEC_DEFAULT`` (``execute``) run the same three steps synchronously, with window-manager progress.
"""
import os

import bpy

from ...bridge import retarget
from ...core.progress import scaled
from ...core.retarget.report import format_ranges
from ...properties import KEY_SHAPES, RETARGET_METHODS
from ..polls import active_rig
from ..progress import JobModal, window_progress
from ..reporting import FAILED, attempt

#: The part of the progress bar for reading the source (main thread); the computation has the rest.
READ_SHARE = 0.1


class SHAPESPACE_OT_retarget(JobModal, bpy.types.Operator):
    """Retarget a capture recording, an action or a mesh performance onto the active mesh's shape keys, into a new
action; a recording's head and eye channels can key head, neck and eye bones (Esc cancels a long retarget;
nothing is written then)"""

    bl_idname = "shapespace.retarget"
    bl_label = "Retarget"
    bl_options = {"REGISTER", "UNDO"}
    job_title = "Retarget"

    filepath: bpy.props.StringProperty(name="Capture File", subtype="FILE_PATH",
                                       description="Capture recording: Live Link Face CSV, Face Cap TXT, iFacialMocap, "
                                                   "Audio2Face JSON, MediaPipe JSON/CSV (leave empty to use an action)")
    action: bpy.props.StringProperty(name="Action", description="Source action animating shape keys")
    source_object: bpy.props.StringProperty(
        name="Mesh Performance", description="An animated mesh to fit (same topology, or lm_* landmark groups)")
    method: bpy.props.EnumProperty(name="Method", items=RETARGET_METHODS, default="spacetime")
    key_tolerance: bpy.props.FloatProperty(name="Key Tolerance", default=0.0, min=0.0, max=0.1,
                                           description="Keep the fewest keys within this slider error (0: all)")
    key_shape: bpy.props.EnumProperty(name="Key Shape", items=KEY_SHAPES, default="BEZIER")
    key_pose_action: bpy.props.StringProperty(
        name="Key Poses", description="Learned method: the action keying this rig at the key-pose frames")
    extend_scene_range: bpy.props.BoolProperty(
        name="Extend Scene Range", default=True,
        description="Widen the scene's frame range to include every frame the result keys")
    armature: bpy.props.StringProperty(name="Armature", description="The armature of the head, neck and eye bones")
    head_bone: bpy.props.StringProperty(name="Head", description="Bone keyed from the head rotation")
    neck_bone: bpy.props.StringProperty(name="Neck", description="Bone keyed with a share of the head rotation")
    neck_share: bpy.props.FloatProperty(name="Neck Share", default=0.3, min=0.0, max=1.0, subtype="FACTOR",
                                        description="Part of the head rotation the neck bone takes")
    eye_left_bone: bpy.props.StringProperty(name="Left Eye", description="The character's left eye bone")
    eye_right_bone: bpy.props.StringProperty(name="Right Eye", description="The character's right eye bone")
    mirror: bpy.props.BoolProperty(name="Mirror", default=False,
                                   description="Swap left and right (a mirrored, selfie-view capture)")
    calibrate: bpy.props.BoolProperty(
        name="Calibrate", default=False,
        description="Make the head and eye pose at the Rest Frame the rest pose (as live capture's Calibrate)")
    rest_frame: bpy.props.IntProperty(name="Rest Frame", default=1,
                                      description="Scene frame whose head and eye pose becomes the rest pose")

    @classmethod
    def poll(cls, context):
        return active_rig(cls, context) is not None

    # ------------------------------------------------------------ orchestration
    def _read(self, context, progress=None):
        """The retarget plan read from Blender (:func:`bridge.retarget.read_retarget`), or FAILED (reported)."""
        settings = dict(method=self.method, scene=context.scene, key_tolerance=self.key_tolerance,
                        key_shape=self.key_shape, extend_scene_range=self.extend_scene_range)
        if self.source_object:
            src = bpy.data.objects.get(self.source_object)
            if src is None or src.type != "MESH":
                self.report({"ERROR"}, f"no mesh named {self.source_object!r}")
                return FAILED
            if self.method in ("copy", "learned"):
                self.report({"ERROR"}, "a mesh performance needs a geometric method: perframe or spacetime")
                return FAILED
            return attempt(self, retarget.read_retarget_dense, context.active_object, src, progress=progress,
                           **settings)
        source = bpy.path.abspath(self.filepath) if self.filepath else self.action
        if not source:
            self.report({"ERROR"}, "choose a CSV file, an action or a mesh performance")
            return FAILED
        bones = retarget.HeadEyeBones(self.armature, self.head_bone, self.neck_bone, self.eye_left_bone,
                                      self.eye_right_bone, self.neck_share, self.mirror,
                                      float(self.rest_frame) if self.calibrate else None)
        return attempt(self, retarget.read_retarget, context.active_object, source,
                       key_pose_action=self.key_pose_action or None, bones=bones, **settings)

    def _done(self, rep):
        """Report a written result (or a failure) and give the operator's return value."""
        if rep is FAILED:
            return {"CANCELLED"}
        for issue in rep.issues:
            self.report({"WARNING"}, issue.message)
        self.report({"INFO"}, result_message(rep))
        return {"FINISHED"}

    def execute(self, context):
        with window_progress(context) as progress:
            plan = self._read(context, scaled(progress, 0.0, READ_SHARE))
            if plan is FAILED:
                return {"CANCELLED"}
            outcome = attempt(self, retarget.compute_retarget, plan, scaled(progress, READ_SHARE, 1.0))
            if outcome is FAILED:
                return {"CANCELLED"}
            return self._done(attempt(self, retarget.write_retarget, outcome, context.scene))

    def invoke(self, context, event):
        if getattr(context, "window", None) is None:          # no event loop to poll from: run it here
            return self.execute(context)
        with window_progress(context) as progress:             # reading a mesh performance takes a while
            plan = self._read(context, scaled(progress, 0.0, READ_SHARE))
        if plan is FAILED:
            return {"CANCELLED"}
        label = f"Retargeting {os.path.basename(plan.report.source)} onto {plan.obj_name} ({plan.method})"
        return self.start_job(context, retarget.start_retarget_job(plan), label, READ_SHARE)

    def job_finished(self, context, job):
        return self._done(attempt(self, retarget.finish_retarget_job, job, context.scene))


def result_message(rep) -> str:
    """The one-line summary of a written retarget: action, frames, error, clipped frames, scene range."""
    text = f"{rep.action}: {rep.frames} frames"
    if rep.frame_range:
        text += f" ({rep.frame_range[0]:g}–{rep.frame_range[1]:g})"
    if rep.position_error_mm is not None:
        text += f", position error {rep.position_error_mm:.2g} mm per vertex (30 cm head)"
    if rep.clipped_frames:
        text += f"; beyond the slider ranges at {format_ranges(rep.clipped_frames)}"
    if rep.scene_range_extended:
        text += "; scene range extended"
    return text
