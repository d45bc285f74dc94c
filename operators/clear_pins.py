import bpy

from .polls import active_mesh


class SHAPESPACE_OT_clear_pins(bpy.types.Operator):
    """Remove every pin of the active mesh"""

    bl_idname = "shapespace.clear_pins"
    bl_label = "Clear Pins"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        ob = active_mesh(cls, context)
        if ob is None:
            return False
        if not len(ob.shapespace.pins):
            cls.poll_message_set("The mesh has no pins")
            return False
        return True

    def execute(self, context):
        context.active_object.shapespace.pins.clear()
        context.active_object.shapespace.active_pin = 0
        return {"FINISHED"}
