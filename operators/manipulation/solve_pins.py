import bpy

from ...bridge import manipulation
from ...core.result import ShapeSpaceError, Status
from ..polls import pinned_rig


class SHAPESPACE_OT_solve_pins(bpy.types.Operator):
    """Move a pin's target (optional) and set the sliders so every pin reaches its target.
The scriptable form of a viewport drag"""

    bl_idname = "shapespace.solve_pins"
    bl_label = "Solve Pins"
    bl_options = {"REGISTER", "UNDO"}

    pin: bpy.props.IntProperty(name="Pin", default=-1, description="Pin to move first; -1 moves none")
    target: bpy.props.FloatVectorProperty(name="Target", size=3, subtype="XYZ",
                                          description="New target of that pin, shape-key space")
    key: bpy.props.BoolProperty(name="Key Sliders", description="Key the changed sliders at the current frame")

    @classmethod
    def poll(cls, context):
        return pinned_rig(cls, context) is not None

    def execute(self, context):
        ob = context.active_object
        try:
            if self.pin >= 0:
                manipulation.set_pin_target(ob, self.pin, self.target)
            before = manipulation.current_sliders(ob)
            result = manipulation.solve_pins(ob)
            if self.key:
                manipulation.key_changed(ob, before, result.weights, context.scene.frame_current)
        except ShapeSpaceError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        level = {"INFO"} if result.status == Status.OK else {"WARNING"}
        self.report(level, f"{result.message}; largest pin error {result.residuals.max():.4g}")
        return {"FINISHED"}
