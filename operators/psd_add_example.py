import bpy

from ..bridge import posespace
from ..core.result import ShapeSpaceError
from .polls import psd_mesh


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
        try:
            name = posespace.add_example(ob, self.name or None, self.sculpt_copy)
            issues = posespace.flag_examples(ob)
        except ShapeSpaceError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        for issue in issues:
            self.report({"WARNING"}, issue.message)
        self.report({"INFO"}, f"Added example {name}: sculpt {name}{posespace.SCULPT_SUFFIX}, then Apply")
        return {"FINISHED"}
