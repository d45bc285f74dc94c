import bpy

from ...bridge.rig import stored
from ..polls import control_face
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_clear_controls(bpy.types.Operator):
    """Remove the face's stored control set (every channel, and damaged data)"""

    bl_idname = "shapespace.clear_controls"
    bl_label = "Clear Controls"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return control_face(cls, context) is not None

    def execute(self, context):
        face = control_face(self, context)
        count = attempt(self, stored.clear, face)
        if count is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"{face.name}: cleared {count} channels")
        return {"FINISHED"}
