import bpy

from ...bridge import facespace
from ..polls import animated_object
from ..progress import window_progress
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_inpaint_gap(bpy.types.Operator):
    """Fill a gap in one animation curve from the statistics of the rest of the animation (covariance
inpainting, thesis 9.3): known frames stay exact, the gap gets one key per frame"""

    bl_idname = "shapespace.inpaint_gap"
    bl_label = "Inpaint Gap"
    bl_options = {"REGISTER", "UNDO"}

    data_path: bpy.props.StringProperty(name="Curve", description='e.g. key_blocks["jawOpen"].value or '
                                                                  'pose.bones["LeftLeg"].rotation_euler')
    index: bpy.props.IntProperty(name="Index", default=0, min=0)
    frame_start: bpy.props.IntProperty(name="Gap From")
    frame_end: bpy.props.IntProperty(name="Gap To")
    use_other_channels: bpy.props.BoolProperty(
        name="Use Other Curves", default=True,
        description="Let the other curves of the action, known in the gap, inform the fill")

    @classmethod
    def poll(cls, context):
        return animated_object(cls, context) is not None

    def execute(self, context):
        with window_progress(context) as progress:
            rep = attempt(self, facespace.inpaint_gap, context.active_object, self.data_path, self.index,
                          self.frame_start, self.frame_end, self.use_other_channels, progress=progress)
        if rep is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"{rep.frames} frames filled from {rep.channels} curve(s): {rep.message}")
        return {"FINISHED"}
