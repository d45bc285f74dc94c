import bpy

from ...bridge import inventory
from ..polls import active_mesh


class SHAPESPACE_OT_check_rig(bpy.types.Operator):
    """Check the active mesh's shape keys and skin for problems ShapeSpace solvers care about
(empty or duplicate targets, NaN coordinates, changed topology, unweighted vertices, orphan groups)"""

    bl_idname = "shapespace.check_rig"
    bl_label = "Check Rig"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        return active_mesh(cls, context, editable=False) is not None

    def execute(self, context):
        found = inventory.check_object(context.active_object)
        errors = [i for i in found if i.severity == "error"]
        for issue in found:
            self.report({"ERROR" if issue.severity == "error" else "WARNING"}, issue.message)
        if errors:
            return {"CANCELLED"}
        if not found:
            self.report({"INFO"}, f"{context.active_object.name}: no problems found")
        return {"FINISHED"}
