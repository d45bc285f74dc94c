import bpy

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
        st = context.active_object.shapespace
        index = st.active_pin if self.index < 0 else self.index
        if not 0 <= index < len(st.pins):
            self.report({"ERROR"}, f"there is no pin {index}")
            return {"CANCELLED"}
        st.pins.remove(index)
        st.active_pin = min(st.active_pin, len(st.pins) - 1)
        return {"FINISHED"}
