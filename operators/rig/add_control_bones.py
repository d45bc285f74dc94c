import bpy

from ...bridge.rig import stored
from ..polls import control_face
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_add_control_bones(bpy.types.Operator):
    """Add the selected pose bones' rotation (in each bone's rotation mode) and location axes to the face's control
set, leaving out locked axes, axes held still by constraints and the location of connected bones"""

    bl_idname = "shapespace.add_control_bones"
    bl_label = "Add Selected Bones"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        ob = context.active_object
        if ob is None or ob.type != "ARMATURE" or ob.mode != "POSE":
            cls.poll_message_set("Select bones of the face's armature in Pose Mode")
            return False
        if not context.selected_pose_bones:
            cls.poll_message_set(f"No bones of '{ob.name}' are selected")
            return False
        return control_face(cls, context) is not None

    def execute(self, context):
        face = control_face(self, context)
        arm = context.active_object
        names = [pb.name for pb in context.selected_pose_bones if pb.id_data == arm]
        done = attempt(self, stored.add_bones, face, arm, names)
        if done is FAILED:
            return {"CANCELLED"}
        added, skipped = done
        note = f"; left out {len(skipped)} locked or held axes" if skipped else ""
        self.report({"INFO"}, f"{face.name}: added {len(added)} channels{note}")
        return {"FINISHED"}
