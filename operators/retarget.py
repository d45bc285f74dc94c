import bpy

from ..bridge import retarget
from .polls import active_rig
from .reporting import FAILED, attempt


class SHAPESPACE_OT_retarget(bpy.types.Operator):
    """Retarget a Live Link Face CSV or an action onto the active mesh's shape keys, into a new action"""

    bl_idname = "shapespace.retarget"
    bl_label = "Retarget"
    bl_options = {"REGISTER", "UNDO"}

    filepath: bpy.props.StringProperty(name="CSV File", subtype="FILE_PATH",
                                       description="Live Link Face CSV (leave empty to use an action)")
    action: bpy.props.StringProperty(name="Action", description="Source action animating shape keys")
    method: bpy.props.EnumProperty(
        name="Method",
        items=[("copy", "Copy", "Copy the mapped channels (corresponding parameterisation)"),
               ("perframe", "Per Frame", "Fit the sliders to the source motion frame by frame"),
               ("spacetime", "Space-Time", "Match the motion's velocities (keeps its shape at slider limits)")],
        default="spacetime")
    key_tolerance: bpy.props.FloatProperty(name="Key Tolerance", default=0.0, min=0.0, max=0.1,
                                           description="Keep the fewest keys within this slider error (0: all)")

    @classmethod
    def poll(cls, context):
        return active_rig(cls, context) is not None

    def execute(self, context):
        source = bpy.path.abspath(self.filepath) if self.filepath else self.action
        if not source:
            self.report({"ERROR"}, "choose a CSV file or an action")
            return {"CANCELLED"}
        rep = attempt(self, retarget.retarget, context.active_object, source, self.method,
                      key_tolerance=self.key_tolerance)
        if rep is FAILED:
            return {"CANCELLED"}
        for msg in rep["issues"]:
            self.report({"WARNING"}, msg)
        self.report({"INFO"}, f"{rep['action']}: {rep['frames']} frames, {rep['mapped_channels']} channels, "
                              f"velocity error {rep['velocity_error_rms']:.2g}")
        return {"FINISHED"}
