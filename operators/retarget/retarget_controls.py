"""Retarget onto Rig Controls: a capture recording or a shape-key action solved per frame onto the control set
stored on the face (bones, custom properties, sliders), keyed on their datablocks' actions with key reduction.

The solve evaluates the rig through Blender's depsgraph (main thread only): from the UI the job is a
:class:`bridge.rig.steps.SteppedJob` stepped by :class:`operators.progress.SteppedJobModal`'s timer (progress, Esc
cancels, nothing written, the rig put back); scripts, redo and ``EXEC_DEFAULT`` run the same steps in one go.
Per frame only here: the space-time and cloning routes are on the command line (``retarget --controls … --method``).
"""
import os

import bpy

from ...bridge.rig import steps, stored
from ...bridge.rig.last_take import summary
from ..polls import active_rig
from ..progress import SteppedJobModal
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_retarget_controls(SteppedJobModal, bpy.types.Operator):
    """Retarget a capture recording or a shape-key action onto the rig controls stored on the active face, per frame,
into new actions on the armature (or other owners) with key reduction (Esc cancels; nothing is written then)"""

    bl_idname = "shapespace.retarget_controls"
    bl_label = "Retarget onto Rig Controls"
    bl_options = {"REGISTER", "UNDO"}
    job_title = "Retarget onto rig controls"

    filepath: bpy.props.StringProperty(name="Capture File", subtype="FILE_PATH",
                                       description="Capture recording (Live Link Face CSV, Face Cap, …); leave empty "
                                                   "to use an action")
    action: bpy.props.StringProperty(name="Action", description="Source action animating shape keys")
    key_tolerance: bpy.props.FloatProperty(
        name="Key Tolerance", default=0.0, min=0.0, max=0.01, precision=5, subtype="DISTANCE",
        description="Keep the fewest keys whose surface stays within this distance of every frame (0: all)")

    @classmethod
    def poll(cls, context):
        ob = active_rig(cls, context)
        if ob is None:
            return False
        if stored.PROP not in ob:
            cls.poll_message_set(f"'{ob.name}' has no control set: propose or add its rig's controls (Rig ▸ "
                                 "Controls)")
            return False
        return True

    def _read(self, context):
        """(face, control set, source) or FAILED (reported)."""
        ob = context.active_object
        source = bpy.path.abspath(self.filepath) if self.filepath else self.action
        if not source:
            self.report({"ERROR"}, "choose a capture file or an action")
            return FAILED
        controls = attempt(self, stored.control_set, ob)
        return FAILED if controls is FAILED else (ob, controls, source)

    def _start(self, context, plan):
        ob, controls, source = plan
        name = f"{ob.name}_{os.path.splitext(os.path.basename(str(source)))[0]}"
        return steps.start_retarget(ob, controls, source, scene=context.scene, action_name=name)

    def _done(self, rep):
        if rep is FAILED:
            return {"CANCELLED"}
        for issue in rep.issues:
            self.report({"WARNING"}, issue.message)
        self.report({"INFO"}, summary(rep))
        return {"FINISHED"}

    def execute(self, context):
        plan = self._read(context)
        if plan is FAILED:
            return {"CANCELLED"}
        job = self.run_here(context, self._start(context, plan))
        return self._done(attempt(self, steps.finish_retarget, job, plan[0], plan[2], self.key_tolerance))

    def invoke(self, context, event):
        if getattr(context, "window", None) is None:          # no event loop to poll from: run it here
            return self.execute(context)
        plan = self._read(context)
        if plan is FAILED:
            return {"CANCELLED"}
        self._plan = plan
        label = f"Retargeting {os.path.basename(str(plan[2]))} onto the rig controls of {plan[0].name} (per frame)"
        return self.start_job(context, self._start(context, plan), label)

    def job_finished(self, context, job):
        ob, _controls, source = self._plan
        return self._done(attempt(self, steps.finish_retarget, job, ob, source, self.key_tolerance))
