import bpy

from ...bridge import manipulation
from ..polls import mesh_with_pins


class SHAPESPACE_OT_clear_pins(bpy.types.Operator):
    """Remove every pin of the active mesh"""

    bl_idname = "shapespace.clear_pins"
    bl_label = "Clear Pins"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return mesh_with_pins(cls, context) is not None

    def execute(self, context):
        manipulation.clear_pins(context.active_object)
        return {"FINISHED"}
