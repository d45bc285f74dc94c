import bpy

from ...bridge import live
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_live_calibrate(bpy.types.Operator):
    """Make the actor's current face and head pose the rest pose (they become zero)"""

    bl_idname = "shapespace.live_calibrate"
    bl_label = "Calibrate Neutral"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        if not live.is_running():
            cls.poll_message_set("Start live capture first")
            return False
        return True

    def execute(self, context):
        if attempt(self, live.calibrate) is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, "neutral calibrated")
        return {"FINISHED"}
