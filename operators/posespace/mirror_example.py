import bpy

from ...bridge import posespace
from ..polls import psd_mesh
from ..reporting import FAILED, attempt, report_issues


class SHAPESPACE_OT_psd_mirror_example(bpy.types.Operator):
    """Add the left↔right mirror of the active example (mirrored pose and corrective)"""

    bl_idname = "shapespace.psd_mirror_example"
    bl_label = "Mirror Example"
    bl_options = {"REGISTER", "UNDO"}

    tolerance: bpy.props.FloatProperty(
        name="Tolerance", default=1e-4, min=0.0, max=0.1,
        description="How far (fraction of the mesh size) a vertex may be from its mirror partner")

    @classmethod
    def poll(cls, context):
        return psd_mesh(cls, context, need_example=True) is not None

    def execute(self, context):
        ob = context.active_object
        st = ob.shapespace_psd
        name = attempt(self, posespace.mirror_example, ob, st.examples[st.active_example].name, self.tolerance)
        if name is FAILED:
            return {"CANCELLED"}
        report_issues(self, posespace.flag_examples(ob))
        self.report({"INFO"}, f"Added mirrored example {name}")
        return {"FINISHED"}
