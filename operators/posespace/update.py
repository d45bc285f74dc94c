import bpy

from ...bridge import posespace
from ..polls import psd_mesh
from ..progress import window_progress
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_psd_update(bpy.types.Operator):
    """Set the pose-space correctives for the current pose"""

    bl_idname = "shapespace.psd_update"
    bl_label = "Update Correctives"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return psd_mesh(cls, context, need_example=True) is not None

    def execute(self, context):
        with window_progress(context) as progress:
            progress(0.0)
            done = attempt(self, posespace.preview, context.active_object)
        return {"CANCELLED"} if done is FAILED else {"FINISHED"}
