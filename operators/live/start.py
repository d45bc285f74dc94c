import bpy

from ...bridge import live
from ...bridge.rig import live as rig_live
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_live_start(bpy.types.Operator):
    """Listen for a phone's face capture and drive the target rig with it"""

    bl_idname = "shapespace.live_start"
    bl_label = "Start"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        if live.is_running():
            cls.poll_message_set("Live capture is already running")
            return False
        st = context.scene.shapespace_live
        ob = st.target or context.active_object
        if ob is None or ob.type != "MESH" or ob.data.shape_keys is None:
            cls.poll_message_set("Choose a target mesh with shape keys (or make one active)")
            return False
        if st.method == "CONTROLS" and not rig_live.has_controls(ob):
            cls.poll_message_set(f"'{ob.name}' has no stored control set: add its controls first (Any Rig panel)")
            return False
        if ob.mode == "EDIT":
            cls.poll_message_set(f"'{ob.name}' is in Edit Mode: leave Edit Mode first")
            return False
        return True

    def execute(self, context):
        st = context.scene.shapespace_live
        result = attempt(self, live.start, context.scene, st.target or context.active_object)
        if result is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, live.RUNTIME.message)
        return {"FINISHED"}
