import bpy

from ...bridge import symmetry
from ..polls import sculpted_key
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_split_shape(bpy.types.Operator):
    """Split the active shape key into <name>_L and <name>_R with a smooth falloff across the centre line; the
halves add up exactly to the original, which is kept (muted)"""

    bl_idname = "shapespace.split_shape"
    bl_label = "Split Shape L/R"
    bl_options = {"REGISTER", "UNDO"}

    falloff: bpy.props.FloatProperty(name="Falloff", default=0.05, soft_min=0.0, soft_max=1.0, precision=3,
                                     description="Width of the blend across the centre line, as a fraction of "
                                                 "the mesh's bounding-box diagonal (0: a hard cut)")

    @classmethod
    def poll(cls, context):
        return sculpted_key(cls, context, "source") is not None

    def execute(self, context):
        ob = context.active_object
        halves = attempt(self, lambda: symmetry.split_shape(ob, ob.active_shape_key.name, symmetry.map_for(ob)[0],
                                                             self.falloff))
        if halves is FAILED:
            return {"CANCELLED"}
        left, right = halves
        self.report({"INFO"}, f"Split into {left} and {right} (original muted, kept)")
        return {"FINISHED"}
