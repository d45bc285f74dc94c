import bpy

from ...bridge import symmetry
from ...core import symmetry as core_symmetry
from ..polls import sculpted_key
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_combine_shapes(bpy.types.Operator):
    """Combine the active left/right shape key and its other side (jawOpen_L + jawOpen_R) into one new key;
the halves are kept"""

    bl_idname = "shapespace.combine_shapes"
    bl_label = "Combine L/R"
    bl_options = {"REGISTER", "UNDO"}

    other: bpy.props.StringProperty(name="Other Side", description="The other half (default: the active key's "
                                                                     "counterpart by name)")
    name: bpy.props.StringProperty(name="Name", description="Name of the combined key (default: the active key's "
                                                              "name without its side)")

    @classmethod
    def poll(cls, context):
        return sculpted_key(cls, context, "left or right") is not None

    def execute(self, context):
        ob = context.active_object
        first = ob.active_shape_key.name
        other = self.other or core_symmetry.counterpart_name(first)
        if not other:
            self.report({"ERROR"}, f"{first!r} has no side in its name: set Other Side")
            return {"CANCELLED"}
        name = attempt(self, symmetry.combine_shapes, ob, first, other, self.name)
        if name is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"Combined {first} + {other} into {name} (at value 0; the halves are kept)")
        return {"FINISHED"}
