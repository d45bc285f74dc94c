import bpy

from ...bridge.posespace import finalshape
from ...core.result import Status
from ..polls import psd_mesh
from ..progress import window_progress
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_reinvert_all(bpy.types.Operator):
    """Recompute every example's corrective exactly from its stored sculpt (final shape) through the rig as it
is now; nothing is written when any of them cannot be re-inverted"""

    bl_idname = "shapespace.reinvert_all"
    bl_label = "Re-invert All"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return psd_mesh(cls, context, need_example=True) is not None

    def execute(self, context):
        ob = context.active_object
        with window_progress(context) as progress:
            done = attempt(self, finalshape.reinvert_all, ob, progress=progress)
        if done is FAILED:
            return {"CANCELLED"}
        missing = [ex.name for ex in ob.shapespace_psd.examples if not ex.final_shape]
        if missing:
            self.report({"WARNING"}, f"no final shape (capture it first): {', '.join(missing)}")
        bad = [name for name, result in done if result.status != Status.OK]
        if bad:
            self.report({"WARNING"}, f"not converged: {', '.join(bad)}")
        worst = max((result.residual for _, result in done), default=0.0)
        self.report({"INFO"}, f"Re-inverted {len(done)} examples (largest error {worst:.3g})")
        return {"FINISHED"}
