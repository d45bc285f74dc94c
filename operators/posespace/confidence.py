import bpy

from ...bridge import posespace
from ..polls import psd_mesh
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_psd_confidence(bpy.types.Operator):
    """How well the examples cover the current pose: the Gaussian-process variance of the pose-space
interpolation (0 at an example, 1 far from all), optionally as a vertex-colour heat map (thesis 9.1–9.2)"""

    bl_idname = "shapespace.psd_confidence"
    bl_label = "Pose-Space Confidence"
    bl_options = {"REGISTER", "UNDO"}

    heat_map: bpy.props.BoolProperty(name="Heat Map", default=True,
                                     description="Write the per-vertex uncertainty as a colour attribute")

    @classmethod
    def poll(cls, context):
        return psd_mesh(cls, context, need_example=True) is not None

    def execute(self, context):
        rep = attempt(self, posespace.confidence, context.active_object, self.heat_map)
        if rep is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"pose-space variance {rep['variance']:.3f} over {rep['examples']} examples")
        return {"FINISHED"}
