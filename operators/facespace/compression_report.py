import bpy

from ...bridge import facespace
from ..polls import active_rig, animated_object
from ..progress import window_progress
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_compression_report(bpy.types.Operator):
    """How many PCA components keep the rig's animation within a max vertex error (thesis 3.7.8)"""

    bl_idname = "shapespace.compression_report"
    bl_label = "Compression Report"
    bl_options = {"REGISTER", "UNDO"}

    tolerance: bpy.props.FloatProperty(name="Tolerance", default=0.001, min=1e-7, max=0.5,
                                       description="Max vertex error, as a fraction of the head size")

    @classmethod
    def poll(cls, context):
        return active_rig(cls, context) is not None and animated_object(cls, context) is not None

    def execute(self, context):
        with window_progress(context) as progress:
            rep = attempt(self, facespace.compression_relative, context.active_object, self.tolerance,
                          progress=progress)
        if rep is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"{rep.components} of {rep.targets} components keep {rep.frames} frames "
                              f"within {self.tolerance:g} of the head size ({rep.ratio:.2f}:1)")
        return {"FINISHED"}
