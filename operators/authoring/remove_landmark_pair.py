import bpy

from ...bridge import authoring
from ..polls import active_mesh
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_remove_landmark_pair(bpy.types.Operator):
    """Remove a landmark pair of the active mesh (the last one placed by default)"""

    bl_idname = "shapespace.remove_landmark_pair"
    bl_label = "Remove Landmark Pair"
    bl_options = {"REGISTER", "UNDO"}

    index: bpy.props.IntProperty(name="Index", default=-1, min=-1, description="Pair to remove; −1: the last one")

    @classmethod
    def poll(cls, context):
        ob = active_mesh(cls, context)
        if ob is None:
            return False
        count, problem = authoring.landmark_count(ob)
        if problem or not count:
            cls.poll_message_set(problem or "The mesh has no landmark pairs")
            return False
        return True

    def execute(self, context):
        ob = context.active_object
        count = attempt(self, authoring.remove_landmark, ob, self.index)
        if count is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"removed landmark pair {self.index} ({count} left)" if self.index >= 0 else
                              f"removed the last landmark pair ({count} left)")
        return {"FINISHED"}
