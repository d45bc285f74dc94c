import bpy

from ...bridge import live
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_live_remove_take(bpy.types.Operator):
    """Delete this take (and its bone and cleaned actions)"""

    bl_idname = "shapespace.live_remove_take"
    bl_label = "Remove Take"
    bl_options = {"REGISTER", "UNDO"}

    take: bpy.props.StringProperty(name="Take")

    @classmethod
    def poll(cls, context):
        if live.is_recording():
            cls.poll_message_set("Stop recording first")
            return False
        return True

    def execute(self, context):
        if attempt(self, live.remove_take, self.take) is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"removed {self.take!r}")
        return {"FINISHED"}
