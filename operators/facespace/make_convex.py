import bpy

from ...bridge import facespace
from ..polls import active_rig
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_make_convex(bpy.types.Operator):
    """Move the sliders to the nearest convex combination of the targets and the neutral (each slider in
[0, 1], their sum at most 1): the expression stays inside the rig's hull (thesis 3.7.3)"""

    bl_idname = "shapespace.make_convex"
    bl_label = "Make Convex"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return active_rig(cls, context) is not None

    def execute(self, context):
        rep = attempt(self, facespace.make_convex, context.active_object)
        if rep is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"slider sum {rep.sum_before:.3f} → {rep.sum_after:.3f} "
                              f"(moved {rep.moved:.3f})")
        return {"FINISHED"}
