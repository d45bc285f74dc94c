import bpy

from ...bridge import posespace
from ..polls import psd_mesh
from ..reporting import FAILED, attempt, report_issues


class SHAPESPACE_OT_psd_apply_example(bpy.types.Operator):
    """Store the active example's sculpt as a rest-space corrective (inverting the skinning at its pose)"""

    bl_idname = "shapespace.psd_apply_example"
    bl_label = "Apply Sculpt"
    bl_options = {"REGISTER", "UNDO"}

    remove_copy: bpy.props.BoolProperty(name="Remove Posed Copy", default=False,
                                        description="Delete the sculpt copy once applied")

    @classmethod
    def poll(cls, context):
        ob = psd_mesh(cls, context, need_example=True)
        if ob is None:
            return False
        st = ob.shapespace_psd
        if st.examples[st.active_example].sculpt is None:
            cls.poll_message_set("The active example has no posed copy to apply")
            return False
        return True

    def execute(self, context):
        ob = context.active_object
        st = ob.shapespace_psd
        ex = st.examples[st.active_example]
        result = attempt(self, posespace.apply_example, ob, ex.name)
        if result is FAILED:
            return {"CANCELLED"}
        if self.remove_copy and ex.sculpt is not None:
            bpy.data.objects.remove(ex.sculpt)
        report_issues(self, posespace.flag_examples(ob))
        level = {"INFO"} if result.status == 0 else {"WARNING"}
        self.report(level, f"{ex.name}: {result.message} (largest error {result.residual:.3g})")
        return {"FINISHED"}
