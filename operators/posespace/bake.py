import bpy

from ...bridge import posespace
from ..polls import psd_mesh
from ..progress import window_progress
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_psd_bake(bpy.types.Operator):
    """Bake the correctives over a frame range into shape-key animation, so the file plays back without
ShapeSpace or Python (PSD and Shape-by-Example; only the active method's correctives play)"""

    bl_idname = "shapespace.psd_bake"
    bl_label = "Bake Correctives"
    bl_options = {"REGISTER", "UNDO"}

    frame_start: bpy.props.IntProperty(name="Start", default=1)
    frame_end: bpy.props.IntProperty(name="End", default=250)

    @classmethod
    def poll(cls, context):
        ob = psd_mesh(cls, context, need_example=True)
        if ob is None:
            return False
        if ob.shapespace_psd.method == "WPSD":
            cls.poll_message_set("Weighted PSD is per vertex: it cannot be baked into example-key animation")
            return False
        return True

    def invoke(self, context, event):
        self.frame_start, self.frame_end = context.scene.frame_start, context.scene.frame_end
        return self.execute(context)

    def execute(self, context):
        if self.frame_end < self.frame_start:
            self.report({"ERROR"}, "the frame range is empty (end before start)")
            return {"CANCELLED"}
        ob = context.active_object
        with window_progress(context) as progress:
            count = attempt(self, posespace.bake_weights, ob, context.scene, self.frame_start, self.frame_end,
                            progress=progress)
        if count is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"Baked {count} corrective keys over frames {self.frame_start}–{self.frame_end}")
        return {"FINISHED"}
