import bpy

from ...bridge import live
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_live_record(bpy.types.Operator):
    """Record the solved sliders and bones into a new take (an action, keyed at the scene rate from the current
frame)"""

    bl_idname = "shapespace.live_record"
    bl_label = "Record"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        if not live.is_running():
            cls.poll_message_set("Start live capture first")
            return False
        if live.is_recording():
            cls.poll_message_set("Already recording")
            return False
        return True

    def execute(self, context):
        take = attempt(self, live.record, context.scene, context.scene.shapespace_live.take_name)
        if take is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"recording {take!r}")
        return {"FINISHED"}
