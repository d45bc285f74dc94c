import bpy

from ...bridge import manipulation, shapekeys
from ...core.result import ShapeSpaceError
from ..polls import active_rig


class SHAPESPACE_OT_add_pin(bpy.types.Operator):
    """Pin a surface point of the active mesh (1–3 vertices with barycentric weights)"""

    bl_idname = "shapespace.add_pin"
    bl_label = "Add Pin"
    bl_options = {"REGISTER", "UNDO"}

    vertices: bpy.props.IntVectorProperty(name="Vertices", size=3, min=0)
    weights: bpy.props.FloatVectorProperty(name="Weights", size=3, default=(1.0, 0.0, 0.0))
    target: bpy.props.FloatVectorProperty(name="Target", size=3, subtype="XYZ")
    use_target: bpy.props.BoolProperty(
        name="Use Target", description="Give the target; otherwise the pin stays where the point is now")
    stationary: bpy.props.BoolProperty(name="Stationary", description="Pin the point in place")

    @classmethod
    def poll(cls, context):
        return active_rig(cls, context) is not None

    def execute(self, context):
        ob = context.active_object
        pin = manipulation.stored_pin(self.vertices, self.weights)
        target = self.target if self.use_target else None
        try:
            model = shapekeys.read_blendshape_model(ob)
            index = manipulation.add_pin(ob, pin, target, self.stationary, model=model)
        except ShapeSpaceError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, f"Added pin {index}")
        return {"FINISHED"}
