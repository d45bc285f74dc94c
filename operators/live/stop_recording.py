import bpy

from ...bridge import live
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_live_stop_recording(bpy.types.Operator):
    """Finish the take (the rig plays it); optionally refit it space-time and reduce its keys into
'<take> clean'"""

    bl_idname = "shapespace.live_stop_recording"
    bl_label = "Stop Recording"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        if not live.is_recording():
            cls.poll_message_set("Not recording")
            return False
        return True

    def execute(self, context):
        st = context.scene.shapespace_live
        result = attempt(self, live.stop_recording, st.clean_spacetime, st.clean_tolerance)
        if result is FAILED:
            return {"CANCELLED"}
        take, clean = result
        self.report({"INFO"}, f"take {take!r} recorded" + (f", cleaned into {clean!r}" if clean else ""))
        return {"FINISHED"}
