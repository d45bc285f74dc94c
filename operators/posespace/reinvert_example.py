import bpy

from ...bridge.posespace import finalshape
from ...core.result import Status
from ..polls import psd_mesh
from ..progress import window_progress
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_reinvert_example(bpy.types.Operator):
    """Recompute the active example's corrective exactly from its stored sculpt (final shape) through the rig as
it is now: after re-weighting, moving a bone's rest pose or changing a modifier"""

    bl_idname = "shapespace.reinvert_example"
    bl_label = "Re-invert"
    bl_options = {"REGISTER", "UNDO"}

    example: bpy.props.StringProperty(name="Example", description="Example to re-invert (default: the active one)")

    @classmethod
    def poll(cls, context):
        return psd_mesh(cls, context, need_example=True) is not None

    def execute(self, context):
        ob = context.active_object
        st = ob.shapespace_psd
        name = self.example or st.examples[st.active_example].name
        with window_progress(context) as progress:
            result = attempt(self, finalshape.reinvert_example, ob, name, progress=progress)
        if result is FAILED:
            return {"CANCELLED"}
        level = {"INFO"} if result.status == Status.OK else {"WARNING"}
        self.report(level, f"Re-inverted {name}: {result.message} (largest error {result.residual:.3g})")
        return {"FINISHED"}
