"""Preview Registration: read (main thread) → register (a worker thread when invoked from the UI) → show the
registered source neutral as a wireframe (main thread).

From the UI the registration runs in a :class:`core.jobs.BackgroundJob` with window-manager progress and a
status-bar line; Esc cancels it and nothing changes (the previous preview stays).  Scripts and redo run the
same three steps synchronously.
"""
import bpy

from ...bridge import authoring
from ..progress import ThreeStepJob
from ..reporting import FAILED, attempt
from ._polls import transfer_target


class SHAPESPACE_OT_preview_registration(ThreeStepJob, bpy.types.Operator):
    """Register the source rig's neutral onto the active mesh and show it as a wireframe over it (one preview
object, removed by Clear Preview and by Transfer Shapes; Esc cancels)"""

    bl_idname = "shapespace.preview_registration"
    bl_label = "Preview Registration"
    bl_options = {"REGISTER", "UNDO"}
    job_title = "Registration preview"
    compute_step = staticmethod(authoring.compute_preview)
    write_step = staticmethod(authoring.write_preview)
    start_step = staticmethod(authoring.start_preview_job)
    finish_step = staticmethod(authoring.finish_preview_job)

    @classmethod
    def poll(cls, context):
        return transfer_target(cls, context, need_landmarks=authoring.MIN_LANDMARKS) is not None

    def read_plan(self, context):
        ob = context.active_object
        return attempt(self, authoring.read_preview, ob.shapespace_authoring.source, ob)

    @staticmethod
    def job_label(plan):
        return f"Registering {plan.source} onto {plan.target}"

    def done(self, shown):
        """Report the preview shown (or a failure) and give the operator's return value."""
        if shown is FAILED:
            return {"CANCELLED"}
        preview, result = shown
        if result.status != 0 and result.message:
            self.report({"WARNING"}, f"registration: {result.message}")
        self.report({"INFO"}, f"{preview.name}: residual {result.value.residual_mm:.2f} mm")
        return {"FINISHED"}
