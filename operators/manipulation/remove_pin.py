import bpy

from ...bridge import manipulation
from ...core.result import ShapeSpaceError
from ..polls import mesh_with_pins


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
        try:
            manipulation.remove_pin(context.active_object, self.index)
        except ShapeSpaceError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        return {"FINISHED"}
