import bpy

from ...bridge import authoring
from ...core.result import ShapeSpaceError
from ._polls import transfer_target
from ..progress import window_progress


class SHAPESPACE_OT_preview_registration(bpy.types.Operator):
    """Register the source rig's neutral onto the active mesh and show it as a wireframe over it (one preview
object, removed by Clear Preview and by Transfer Shapes)"""

    bl_idname = "shapespace.preview_registration"
    bl_label = "Preview Registration"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return transfer_target(cls, context, need_landmarks=authoring.MIN_LANDMARKS) is not None

    def execute(self, context):
        ob = context.active_object
        try:
            with window_progress(context) as progress:
                preview, result = authoring.show_preview(ob.shapespace_authoring.source, ob, progress)
        except ShapeSpaceError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        if result.status != 0 and result.message:
            self.report({"WARNING"}, f"registration: {result.message}")
        self.report({"INFO"}, f"{preview.name}: residual {result.value.residual_mm:.2f} mm")
        return {"FINISHED"}
