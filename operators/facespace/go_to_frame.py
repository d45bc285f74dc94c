import bpy

from ...bridge import facespace


class SHAPESPACE_OT_go_to_frame(bpy.types.Operator):
    """Jump to this frame"""

    bl_idname = "shapespace.go_to_frame"
    bl_label = "Go to Frame"
    bl_options = {"REGISTER", "UNDO"}

    frame: bpy.props.IntProperty(name="Frame")

    @classmethod
    def poll(cls, context):
        if context.scene is None:
            cls.poll_message_set("No scene")
            return False
        return True

    def execute(self, context):
        facespace.set_frame(context.scene, self.frame)
        return {"FINISHED"}
