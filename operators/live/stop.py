import bpy

from ...bridge import live


class SHAPESPACE_OT_live_stop(bpy.types.Operator):
    """Stop receiving (a take being recorded is finished and kept)"""

    bl_idname = "shapespace.live_stop"
    bl_label = "Stop"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        if not live.is_running():
            cls.poll_message_set("Live capture is not running")
            return False
        return True

    def execute(self, context):
        take = live.stop()
        self.report({"INFO"}, f"stopped; take {take!r} kept" if take else "stopped")
        return {"FINISHED"}
