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
        ob = context.active_object
        a, b = self.frame_start, self.frame_end
        if a < 0 or b < 0:
            keys = attempt(self, facespace.bracketing_keys, ob, context.scene.frame_current)
            if keys is FAILED:
                return {"CANCELLED"}
            a, b = keys if (a < 0 and b < 0) else (a if a >= 0 else keys[0], b if b >= 0 else keys[1])
        n = attempt(self, facespace.fill_between, ob, a, b, self.mode)
        if n is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"{n} frames between {a} and {b} ({self.mode.lower()})")
        return {"FINISHED"}
