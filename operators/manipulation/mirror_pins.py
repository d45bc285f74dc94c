import bpy

from ...bridge import manipulation
from ..polls import active_rig
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_mirror_pins(bpy.types.Operator):
    """Give every pin without a mirror its mirror pin (through the mesh's stored mirror map): the mirrored
point with the mirrored target; a pin on the centre line is its own mirror"""

    bl_idname = "shapespace.mirror_pins"
    bl_label = "Mirror Pins"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        ob = active_rig(cls, context)
        if ob is not None and not len(ob.shapespace.pins):
            cls.poll_message_set("The mesh has no pins")
            return False
        return ob is not None

    def execute(self, context):
        ob = context.active_object
        counts = attempt(self, lambda: manipulation.mirror_pins(ob, manipulation.rig_model(ob)))
        if counts is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"Mirror Pins: {counts['added']} added, {counts['linked']} linked to an existing "
                              f"mirror pin, {counts['centre']} on the centre line")
        return {"FINISHED"}
