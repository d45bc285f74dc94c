import bpy

from ...bridge import manipulation
from ..polls import mesh_with_pins
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_remove_pin(bpy.types.Operator):
    """Remove a pin (the active one by default)"""

    bl_idname = "shapespace.remove_pin"
    bl_label = "Remove Pin"
    bl_options = {"REGISTER", "UNDO"}

    index: bpy.props.IntProperty(name="Index", default=-1, description="Pin to remove; -1 for the active pin")

    @classmethod
    def poll(cls, context):
        return mesh_with_pins(cls, context) is not None

    def execute(self, context):
        if attempt(self, manipulation.remove_pin, context.active_object, self.index) is FAILED:
            return {"CANCELLED"}
        return {"FINISHED"}
