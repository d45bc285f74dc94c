import bpy

from ...bridge.rig import stored
from ..polls import control_face
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_remove_control(bpy.types.Operator):
    """Remove one channel from the face's control set"""

    bl_idname = "shapespace.remove_control"
    bl_label = "Remove Channel"
    bl_options = {"REGISTER", "UNDO"}

    index: bpy.props.IntProperty(name="Index", min=0)

    @classmethod
    def poll(cls, context):
        return control_face(cls, context) is not None

    def execute(self, context):
        face = control_face(self, context)
        gone = attempt(self, stored.remove, face, self.index)
        if gone is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"{face.name}: removed {gone.label}")
        return {"FINISHED"}
