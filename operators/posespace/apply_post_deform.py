import bpy

from ...bridge import posespace
from ...bridge.posespace import postdeform
from ...core.result import Status
from ..polls import psd_sculpt
from ..reporting import FAILED, attempt
from ..progress import window_progress


class SHAPESPACE_OT_apply_post_deform(bpy.types.Operator):
    """Store the active example's sculpt as a post-deformation corrective: offsets in a frame of the deformed
surface, added after the armature by a generated Geometry Nodes modifier (plays without the add-on, survives
re-weighting without re-inversion)"""

    bl_idname = "shapespace.apply_post_deform"
    bl_label = "Apply as Post-Deformation"
    bl_options = {"REGISTER", "UNDO"}

    remove_copy: bpy.props.BoolProperty(name="Remove Posed Copy", default=False,
                                        description="Delete the sculpt copy once applied")

    @classmethod
    def poll(cls, context):
        return psd_sculpt(cls, context) is not None

    def execute(self, context):
        ob = context.active_object
        st = ob.shapespace_psd
        name = st.examples[st.active_example].name
        with window_progress(context) as progress:
            result = attempt(self, postdeform.apply_post_deform, ob, name, progress=progress)
        if result is FAILED:
            return {"CANCELLED"}
        if self.remove_copy:
            posespace.remove_sculpt_copy(ob, name)
        level = {"INFO"} if result.status == Status.OK else {"WARNING"}
        self.report(level, f"{name}: post-deformation corrective stored (modifier '{postdeform.MODIFIER}')")
        return {"FINISHED"}
