import bpy

from ...bridge import facespace
from ..polls import active_rig
from ..progress import window_progress
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_analyse_rig(bpy.types.Operator):
    """Coherence image of the rig's targets, near-duplicate and empty targets, and the sparsity of its
animation in blendshape vs PCA form (thesis 3.7)"""

    bl_idname = "shapespace.analyse_rig"
    bl_label = "Analyse Rig"
    bl_options = {"REGISTER", "UNDO"}

    filepath: bpy.props.StringProperty(name="PNG", subtype="FILE_PATH",
                                       description="Also write the coherence image here (empty: pack it)")
    threshold: bpy.props.FloatProperty(name="Similar Above", default=0.95, min=0.0, max=1.0,
                                       description="Report target pairs whose coherence exceeds this")

    @classmethod
    def poll(cls, context):
        return active_rig(cls, context) is not None

    def execute(self, context):
        ob = context.active_object
        path = bpy.path.abspath(self.filepath) if self.filepath else None
        with window_progress(context) as progress:
            rep = attempt(self, facespace.analyse, ob, None, path, self.threshold, progress=progress)
        if rep is FAILED:
            return {"CANCELLED"}
        for name in rep.empty_targets:
            self.report({"WARNING"}, f"{name} moves no vertex")
        for a, b, c in rep.similar_pairs:
            self.report({"WARNING"}, f"{a} and {b} nearly duplicate each other (coherence {c:.3f})")
        self.report({"INFO"}, f"mutual coherence {rep.mutual_coherence:.3f}; image {rep.image!r}")
        return {"FINISHED"}
