import bpy

from ...bridge import facespace
from ..polls import prior_rig
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_fill_between(bpy.types.Operator):
    """Key the frames between two keyed expressions: around the face prior's shell (keeps the expression's
strength) or linearly (drifts toward the average face) (thesis 6.5)"""

    bl_idname = "shapespace.fill_between"
    bl_label = "Fill In-Betweens"
    bl_options = {"REGISTER", "UNDO"}

    mode: bpy.props.EnumProperty(
        name="Interpolation",
        items=[("SHELL", "Shell", "Norm-preserving, around the hyperellipsoid of typical faces"),
               ("LINEAR", "Linear", "Straight line between the two expressions")],
        default="SHELL")
    frame_start: bpy.props.IntProperty(name="From", default=-1, description="−1: the key before the current frame")
    frame_end: bpy.props.IntProperty(name="To", default=-1, description="−1: the key after the current frame")

    @classmethod
    def poll(cls, context):
        return prior_rig(cls, context) is not None

    def execute(self, context):
        rep = attempt(self, facespace.fill_around, context.active_object, context.scene.frame_current,
                      self.frame_start, self.frame_end, self.mode)
        if rep is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"{rep.frames} frames between {rep.start} and {rep.end} "
                              f"({self.mode.lower()})")
        return {"FINISHED"}
