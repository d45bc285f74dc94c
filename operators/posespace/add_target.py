import bpy

from ...bridge import posespace
from ..polls import psd_mesh
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_psd_add_target(bpy.types.Operator):
    """Drive a value from pose space (thesis 7.3.3): a bone channel or custom property of the armature,
or a property of the mesh; record its value at each example with Record Targets"""

    bl_idname = "shapespace.psd_add_target"
    bl_label = "Add Driven Target"
    bl_options = {"REGISTER", "UNDO"}

    data_path: bpy.props.StringProperty(name="Data Path", description='e.g. pose.bones["Arm"].scale or ["exertion"]')
    index: bpy.props.IntProperty(name="Index", default=-1, min=-1, description="Array index, −1 for a scalar")
    on_armature: bpy.props.BoolProperty(name="On Armature", default=True,
                                        description="The path is on the armature object (else on the mesh)")

    @classmethod
    def poll(cls, context):
        return psd_mesh(cls, context) is not None

    def execute(self, context):
        added = attempt(self, posespace.add_target, context.active_object, self.data_path, self.index,
                        self.on_armature)
        if added is FAILED:
            return {"CANCELLED"}
        owner, value = added
        self.report({"INFO"}, f"Driving {owner}.{self.data_path} (now {value:g}); record it at each example")
        return {"FINISHED"}
