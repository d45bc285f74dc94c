import bpy

from ...bridge import symmetry
from ..polls import sculpted_key
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_mirror_shape(bpy.types.Operator):
    """Create the mirror image of the active shape key on the other side (browDown_L → browDown_R, otherwise
<name>_mirror), through the mesh's mirror map"""

    bl_idname = "shapespace.mirror_shape"
    bl_label = "Mirror Shape"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return sculpted_key(cls, context, "source") is not None

    def execute(self, context):
        ob = context.active_object
        found = attempt(self, symmetry.map_for, ob)
        if found is FAILED:
            return {"CANCELLED"}
        mmap, stored = found
        mirrored = attempt(self, symmetry.mirror_shape, ob, ob.active_shape_key.name, mmap)
        if mirrored is FAILED:
            return {"CANCELLED"}
        name, res = mirrored
        note = "" if stored else " (no stored mirror map: used an automatic one)"
        if res.status != 0:
            self.report({"WARNING"}, f"Created {name}{note}; {res.message}")
        else:
            self.report({"INFO"}, f"Created {name}{note}")
        return {"FINISHED"}
