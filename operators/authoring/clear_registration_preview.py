import bpy

from ...bridge import authoring
from ..polls import active_mesh


class SHAPESPACE_OT_clear_registration_preview(bpy.types.Operator):
    """Remove the active mesh's registration preview (object and mesh)"""

    bl_idname = "shapespace.clear_registration_preview"
    bl_label = "Clear Preview"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        ob = active_mesh(cls, context)
        if ob is None:
            return False
        if authoring.preview_object(ob) is None:
            cls.poll_message_set("The mesh has no registration preview")
            return False
        return True

    def execute(self, context):
        authoring.clear_preview(context.active_object)
        return {"FINISHED"}
