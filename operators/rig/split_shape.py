import bpy

from ...bridge import symmetry
from ...core.result import ShapeSpaceError
from ..polls import sculpted_key


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
        try:
            mmap, _ = symmetry.map_for(ob)
            left, right = symmetry.split_shape(ob, ob.active_shape_key.name, mmap, self.falloff)
        except ShapeSpaceError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, f"Split into {left} and {right} (original muted, kept)")
        return {"FINISHED"}
