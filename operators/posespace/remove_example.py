import bpy

from ...bridge import posespace
from ..polls import psd_mesh
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_psd_remove_example(bpy.types.Operator):
    """Delete the active example, its corrective shape key and its posed copy"""

    bl_idname = "shapespace.psd_remove_example"
    bl_label = "Remove Example"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return psd_mesh(cls, context, need_example=True) is not None

    def execute(self, context):
        ob = context.active_object
        st = ob.shapespace_psd
        name = attempt(self, posespace.remove_example, ob, st.examples[st.active_example].name)
        if name is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"Removed example {name}")
        return {"FINISHED"}
