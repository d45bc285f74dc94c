import bpy

from ...bridge import facespace
from ..polls import active_rig, animated_object
from ..progress import window_progress
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_learn_face_prior(bpy.types.Operator):
    """Learn the distribution of expressions (a Gaussian over the sliders) from the rig's animation, for the
probability meter and shell in-betweens (thesis ch. 6)"""

    bl_idname = "shapespace.learn_face_prior"
    bl_label = "Learn Face Prior"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return active_rig(cls, context) is not None and animated_object(cls, context) is not None

    def execute(self, context):
        with window_progress(context) as progress:
            rep = attempt(self, facespace.learn_prior, context.active_object, progress=progress)
        if rep is FAILED:
            return {"CANCELLED"}
        self.report({"WARNING"} if rep.regularised else {"INFO"}, rep.message)
        return {"FINISHED"}
