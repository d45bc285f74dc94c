import bpy

from ...bridge import retarget
from ..polls import active_rig
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_discard_retarget(bpy.types.Operator):
    """Discard the last retarget: the rig plays the action it had before, the retargeted action is deleted"""

    bl_idname = "shapespace.discard_retarget"
    bl_label = "Discard Result"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        ob = active_rig(cls, context)
        if ob is not None and not retarget.has_result(ob):
            cls.poll_message_set("Nothing retargeted onto this rig yet")
            return False
        return ob is not None

    def execute(self, context):
        restored = attempt(self, retarget.discard_last, context.active_object)
        if restored is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"back to {restored!r}" if restored else "back to no animation")
        return {"FINISHED"}
