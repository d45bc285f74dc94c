import bpy

from ...bridge import manipulation
from ..polls import active_rig
from ..reporting import FAILED, attempt

SPACE_ITEMS = [
    ("WORLD", "World", "World coordinates of where the point should appear (the 3D cursor, an empty): through "
     "the object's and its parents' transforms and its deform modifiers"),
    ("LOCAL", "Local", "The mesh's own undeformed coordinates: shape-key space, as pins store their targets"),
]


class SHAPESPACE_OT_add_pin(bpy.types.Operator):
    """Pin a surface point of the active mesh (1–3 vertices with barycentric weights)"""

    bl_idname = "shapespace.add_pin"
    bl_label = "Add Pin"
    bl_options = {"REGISTER", "UNDO"}

    vertices: bpy.props.IntVectorProperty(name="Vertices", size=3, min=0)
    weights: bpy.props.FloatVectorProperty(name="Weights", size=3, default=(1.0, 0.0, 0.0))
    target: bpy.props.FloatVectorProperty(name="Target", size=3, subtype="XYZ",
                                          description="Where the pin should go, in the chosen Space")
    use_target: bpy.props.BoolProperty(
        name="Use Target", description="Give the target; otherwise the pin stays where the point is now")
    space: bpy.props.EnumProperty(name="Space", items=SPACE_ITEMS, default="LOCAL",
                                  description="Coordinates the target is given in")
    stationary: bpy.props.BoolProperty(name="Stationary", description="Pin the point in place")

    @classmethod
    def poll(cls, context):
        return active_rig(cls, context) is not None

    def execute(self, context):
        ob = context.active_object
        pin = manipulation.stored_pin(self.vertices, self.weights)
        target = self.target if self.use_target else None
        index = attempt(self, lambda: manipulation.add_pin(ob, pin, target, self.stationary,
                                                           model=manipulation.rig_model(ob), space=self.space,
                                                           depsgraph=context.evaluated_depsgraph_get()))
        if index is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"Added pin {index}")
        return {"FINISHED"}
