import bpy

from ...bridge import posespace
from ..polls import psd_mesh
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_psd_record_targets(bpy.types.Operator):
    """Store the driven targets' current values as the active example's"""

    bl_idname = "shapespace.psd_record_targets"
    bl_label = "Record Targets"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        ob = psd_mesh(cls, context, need_example=True)
        if ob is None:
            return False
        if not len(ob.shapespace_psd.targets):
            cls.poll_message_set("Add a driven target first")
            return False
        return True

    def execute(self, context):
        ob = context.active_object
        st = ob.shapespace_psd
        values = attempt(self, posespace.record_targets, ob, st.examples[st.active_example].name)
        if values is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"Recorded {len(values)} target values")
        return {"FINISHED"}
