import bpy

from ...bridge import authoring
from ..polls import active_mesh


class SHAPESPACE_OT_clear_landmark_pairs(bpy.types.Operator):
    """Remove every landmark pair of the active mesh (also clears stale or damaged landmark data)"""

    bl_idname = "shapespace.clear_landmark_pairs"
    bl_label = "Clear Landmarks"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        ob = active_mesh(cls, context)
        if ob is None:
            return False
        if authoring.LANDMARKS_PROP not in ob:
            cls.poll_message_set("The mesh has no landmark pairs")
            return False
        return True

    def execute(self, context):
        authoring.clear_landmarks(context.active_object)
        return {"FINISHED"}
