import bpy

from ...bridge import symmetry
from ..polls import sculpted_key
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_update_mirrored(bpy.types.Operator):
    """Push the sculpted active shape key onto its mirror: rewrite its other-side key (browDown_L → browDown_R),
or, for a middle shape, mirror its sculpted side onto the other side"""

    bl_idname = "shapespace.update_mirrored"
    bl_label = "Update Mirrored"
    bl_options = {"REGISTER", "UNDO"}

    source: bpy.props.EnumProperty(
        name="Sculpted Side",
        items=(("LEFT", "Left (+X)", "The character's left (Blender's .L side) was sculpted"),
               ("RIGHT", "Right (−X)", "The character's right was sculpted")),
        default="LEFT", description="For a middle shape (no side in its name): the side to keep")

    @classmethod
    def poll(cls, context):
        return sculpted_key(cls, context, "source") is not None

    def execute(self, context):
        ob = context.active_object
        updated = attempt(self, lambda: symmetry.update_mirrored(ob, ob.active_shape_key.name,
                                                                 symmetry.map_for(ob)[0], self.source))
        if updated is FAILED:
            return {"CANCELLED"}
        name, res = updated
        if res.status != 0:
            self.report({"WARNING"}, f"Updated {name}; {res.message}")
        else:
            self.report({"INFO"}, f"Updated {name}")
        return {"FINISHED"}
