import bpy

from ...bridge import posespace
from ..polls import psd_mesh
from ..reporting import FAILED, attempt, report_issues


class SHAPESPACE_OT_psd_move_example(bpy.types.Operator):
    """Make the active example's sculpt apply at the current pose without resculpting (a pseudo-example);
Reset puts it back where it was sculpted"""

    bl_idname = "shapespace.psd_move_example"
    bl_label = "Move Example Here"
    bl_options = {"REGISTER", "UNDO"}

    reset: bpy.props.BoolProperty(name="Reset", description="Back to the pose it was sculpted at")

    @classmethod
    def poll(cls, context):
        return psd_mesh(cls, context, need_example=True) is not None

    def execute(self, context):
        ob = context.active_object
        st = ob.shapespace_psd
        if attempt(self, posespace.move_example, ob, st.examples[st.active_example].name, self.reset) is FAILED:
            return {"CANCELLED"}
        report_issues(self, posespace.flag_examples(ob))
        return {"FINISHED"}
