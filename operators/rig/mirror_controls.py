import bpy

from ...bridge.rig import stored
from ..polls import control_face
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_mirror_controls(bpy.types.Operator):
    """Add the left/right mirror of every sided channel of the face's control set (.L/.R, Left/Right, _L/_R, _l/_r
bones, properties and keys; bounds reflected as Blender's flipped pose reflects the value)"""

    bl_idname = "shapespace.mirror_controls"
    bl_label = "Mirror Controls"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return control_face(cls, context) is not None

    def execute(self, context):
        face = control_face(self, context)
        added = attempt(self, stored.mirror, face)
        if added is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"{face.name}: added {len(added)} mirrored channels" if added
                    else f"{face.name}: every sided channel already has its mirror")
        return {"FINISHED"}
