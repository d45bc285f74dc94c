import bpy

from ...bridge.rig import stored
from ..polls import control_face
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_toggle_control(bpy.types.Operator):
    """Enable or disable one channel of the face's control set (a disabled channel stays stored; solves leave it
where it is)"""

    bl_idname = "shapespace.toggle_control"
    bl_label = "Enable Channel"
    bl_options = {"REGISTER", "UNDO"}

    index: bpy.props.IntProperty(name="Index", min=0)
    enabled: bpy.props.BoolProperty(name="Enabled", default=True)

    @classmethod
    def poll(cls, context):
        return control_face(cls, context) is not None

    def execute(self, context):
        face = control_face(self, context)
        entry = attempt(self, stored.set_enabled, face, self.index, self.enabled)
        if entry is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"{entry.label}: {'enabled' if entry.enabled else 'disabled'}")
        return {"FINISHED"}
