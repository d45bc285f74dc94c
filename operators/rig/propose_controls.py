"""Propose Controls: probe what moves the face, a few channels per modal timer tick (Esc cancels, nothing written).

Probing evaluates the rig through Blender's depsgraph, which only the main thread may drive: the job is a
:class:`bridge.rig.steps.SteppedJob` stepped from the modal timer of :class:`operators.progress.SteppedJobModal`
(progress on the cursor and in the status bar, Esc cancels and the rig is put back exactly).  Scripts, redo and
``EXEC_DEFAULT`` run the same steps in one go with window-manager progress.
"""
import bpy

from ...bridge.rig import steps, stored
from ..polls import control_face
from ..progress import SteppedJobModal
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_propose_controls(SteppedJobModal, bpy.types.Operator):
    """Find the channels that move the face (bone rotation and location axes, shape-key sliders, custom properties
drivers read), probing each through Blender's evaluation, and add them to the face's control set (Esc cancels;
nothing is written then)"""

    bl_idname = "shapespace.propose_controls"
    bl_label = "Propose Controls"
    bl_options = {"REGISTER", "UNDO"}
    job_title = "Propose Controls"

    @classmethod
    def poll(cls, context):
        return control_face(cls, context) is not None

    def _targets(self, context):
        face = control_face(self, context)
        return face, stored.armature_for(face, context.active_object)

    def _done(self, face, found):
        if found is FAILED:
            return {"CANCELLED"}
        report, added = found
        if not report.proposed:
            self.report({"ERROR"}, f"{face.name}: no channel deforms the face; {report.summary()}")
            return {"CANCELLED"}
        self.report({"INFO"}, f"{face.name}: {report.summary()}; {len(added)} added")
        return {"FINISHED"}

    def execute(self, context):
        face, arm = self._targets(context)
        job = self.run_here(context, steps.start_proposal(face, arm))
        return self._done(face, attempt(self, steps.finish_proposal, job, face, arm))

    def invoke(self, context, event):
        if getattr(context, "window", None) is None:          # no event loop to poll from: run it here
            return self.execute(context)
        self._face, self._arm = self._targets(context)
        return self.start_job(context, steps.start_proposal(self._face, self._arm),
                              f"Proposing the controls of {self._face.name}")

    def job_finished(self, context, job):
        return self._done(self._face, attempt(self, steps.finish_proposal, job, self._face, self._arm))
