import bpy

from ...bridge import posespace
from ...core.result import ShapeSpaceError
from ..polls import psd_mesh


class SHAPESPACE_OT_psd_update(bpy.types.Operator):
    """Set the pose-space correctives for the current pose"""

    bl_idname = "shapespace.psd_update"
    bl_label = "Update Correctives"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return psd_mesh(cls, context, need_example=True) is not None

    def execute(self, context):
        try:
            posespace.preview(context.active_object)
        except ShapeSpaceError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        return {"FINISHED"}
