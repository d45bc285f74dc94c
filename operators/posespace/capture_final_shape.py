import bpy

from ...bridge.posespace import finalshape
from ..polls import psd_mesh
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_capture_final_shape(bpy.types.Operator):
    """Store the active example's current corrective, posed at its pose, as its final shape (for examples made
by ShapeSpace 0.1.0, which kept no sculpt): pose the rig at the example first"""

    bl_idname = "shapespace.capture_final_shape"
    bl_label = "Capture Final Shape"
    bl_options = {"REGISTER", "UNDO"}

    example: bpy.props.StringProperty(name="Example", description="Example to capture (default: the active one)")
    replace: bpy.props.BoolProperty(name="Replace", default=False,
                                    description="Overwrite a final shape the example has already")

    @classmethod
    def poll(cls, context):
        return psd_mesh(cls, context, need_example=True) is not None

    def execute(self, context):
        ob = context.active_object
        st = ob.shapespace_psd
        name = self.example or st.examples[st.active_example].name
        count = attempt(self, finalshape.capture_final_shape, ob, name, self.replace)
        if count is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"{name}: final shape captured ({count} sculpted vertices)")
        return {"FINISHED"}
