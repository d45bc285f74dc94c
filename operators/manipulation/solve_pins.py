import bpy

from ...bridge import manipulation
from ..polls import pinned_rig
from ..reporting import FAILED, attempt
from .add_pin import SPACE_ITEMS


class SHAPESPACE_OT_solve_pins(bpy.types.Operator):
    """Move a pin's target (optional) and set the sliders so every pin reaches its target.
The scriptable form of a viewport drag"""

    bl_idname = "shapespace.solve_pins"
    bl_label = "Solve Pins"
    bl_options = {"REGISTER", "UNDO"}

    pin: bpy.props.IntProperty(name="Pin", default=-1, description="Pin to move first; -1 moves none")
    target: bpy.props.FloatVectorProperty(name="Target", size=3, subtype="XYZ",
                                          description="New target of that pin, in the chosen Space")
    space: bpy.props.EnumProperty(name="Space", items=SPACE_ITEMS, default="LOCAL",
                                  description="Coordinates the target is given in")
    key: bpy.props.BoolProperty(name="Key Sliders", description="Key the changed sliders at the current frame")

    @classmethod
    def poll(cls, context):
        return pinned_rig(cls, context) is not None

    def execute(self, context):
        ob = context.active_object
        result = attempt(self, manipulation.solve_to_target, ob, context.evaluated_depsgraph_get(), self.pin,
                         self.target, self.space, context.scene.frame_current if self.key else None)
        if result is FAILED:
            return {"CANCELLED"}
        level, text = manipulation.report_text(result, ob, self.space if self.pin >= 0 else None)
        self.report({level}, text)
        return {"FINISHED"}
