import bpy

from ...bridge import live
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_live_play_take(bpy.types.Operator):
    """Make the take's rig (and armature) play this take"""

    bl_idname = "shapespace.live_play_take"
    bl_label = "Play Take"
    bl_options = {"REGISTER", "UNDO"}

    take: bpy.props.StringProperty(name="Take")

    def execute(self, context):
        if attempt(self, live.play_take, self.take) is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"playing {self.take!r}")
        return {"FINISHED"}
