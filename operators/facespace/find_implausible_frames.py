import bpy

from ...bridge import facespace
from ..polls import prior_rig
from ..progress import window_progress
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_find_implausible_frames(bpy.types.Operator):
    """List the frames whose expression lies outside the face prior's high-probability shell (too extreme,
or too close to the average face)"""

    bl_idname = "shapespace.find_implausible_frames"
    bl_label = "Find Implausible Frames"
    bl_options = {"REGISTER", "UNDO"}

    alpha: bpy.props.FloatProperty(name="Significance", default=0.01, min=1e-6, max=0.5,
                                   description="Flag frames in either tail of this total probability")

    @classmethod
    def poll(cls, context):
        return prior_rig(cls, context) is not None

    def execute(self, context):
        with window_progress(context) as progress:
            found = attempt(self, facespace.flag_implausible_frames, context.active_object, None, self.alpha,
                            progress=progress)
        if found is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"{len(found)} implausible frame(s)")
        return {"FINISHED"}
