import bpy

from ...bridge import posespace
from ..polls import psd_mesh
from ..reporting import FAILED, attempt, report_issues


class SHAPESPACE_OT_psd_add_example(bpy.types.Operator):
    """Record the current pose as a pose-space example: creates its corrective shape key and a posed copy
of the mesh to sculpt the wanted shape on"""

    bl_idname = "shapespace.psd_add_example"
    bl_label = "Add Example"
    bl_options = {"REGISTER", "UNDO"}

    name: bpy.props.StringProperty(name="Name", description="Corrective key name (default PSD_NN)")
    sculpt_copy: bpy.props.BoolProperty(name="Posed Copy", default=True,
                                        description="Create a posed copy of the mesh to sculpt on")

    @classmethod
    def poll(cls, context):
        return psd_mesh(cls, context) is not None

    def execute(self, context):
        ob = context.active_object
        name = attempt(self, posespace.add_example, ob, self.name or None, self.sculpt_copy)
        if name is FAILED:
            return {"CANCELLED"}
        report_issues(self, posespace.flag_examples(ob))
        self.report({"INFO"}, f"Added example {name}: sculpt {name}{posespace.SCULPT_SUFFIX}, then Apply")
        return {"FINISHED"}
