"""Preview Registration: read (main thread) → register (a worker thread when invoked from the UI) → show the
registered source neutral as a wireframe (main thread).

From the UI the registration runs in a :class:`core.jobs.BackgroundJob` with window-manager progress and a
status-bar line; Esc cancels it and nothing changes (the previous preview stays).  Scripts and redo run the
same three steps synchronously.
"""
import bpy

from ...bridge import authoring
from ._polls import transfer_target
from ..progress import JobModal, window_progress
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_preview_registration(JobModal, bpy.types.Operator):
    """Register the source rig's neutral onto the active mesh and show it as a wireframe over it (one preview
object, removed by Clear Preview and by Transfer Shapes; Esc cancels)"""

    bl_idname = "shapespace.preview_registration"
    bl_label = "Preview Registration"
    bl_options = {"REGISTER", "UNDO"}
    job_title = "Registration preview"

    @classmethod
    def poll(cls, context):
        return transfer_target(cls, context, need_landmarks=authoring.MIN_LANDMARKS) is not None

    def _read(self, context):
        ob = context.active_object
        return attempt(self, authoring.read_preview, ob.shapespace_authoring.source, ob)

    def execute(self, context):
        plan = self._read(context)
        if plan is FAILED:
            return {"CANCELLED"}
        with window_progress(context) as progress:
            result = attempt(self, authoring.compute_preview, plan, progress)
        if result is FAILED:
            return {"CANCELLED"}
        return self._done(attempt(self, authoring.write_preview, plan, result))

    def invoke(self, context, event):
        if getattr(context, "window", None) is None:          # no event loop to poll from: run it here
            return self.execute(context)
        plan = self._read(context)
        if plan is FAILED:
            return {"CANCELLED"}
        self._plan = plan
        label = f"Registering {plan.source} onto {plan.target}"
        return self.start_job(context, authoring.start_preview_job(plan), label)

    def job_finished(self, context, job):
        return self._done(attempt(self, authoring.finish_preview_job, job, self._plan))

    def _done(self, shown):
        """Report the preview shown (or a failure) and give the operator's return value."""
        if shown is FAILED:
            return {"CANCELLED"}
        preview, result = shown
        if result.status != 0 and result.message:
            self.report({"WARNING"}, f"registration: {result.message}")
        self.report({"INFO"}, f"{preview.name}: residual {result.value.residual_mm:.2f} mm")
        return {"FINISHED"}
