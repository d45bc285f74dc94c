import bpy

from ...bridge import retarget
from ..polls import active_rig
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_remove_mapping(bpy.types.Operator):
    """Remove a channel-mapping override: the source channel is matched by name again"""

    bl_idname = "shapespace.remove_mapping"
    bl_label = "Remove Channel Mapping"
    bl_options = {"REGISTER", "UNDO"}

    source: bpy.props.StringProperty(name="Source Channel")

    @classmethod
    def poll(cls, context):
        return active_rig(cls, context) is not None

    def execute(self, context):
        if attempt(self, retarget.remove_mapping, context.active_object, self.source) is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"{self.source}: matched by name again")
        return {"FINISHED"}
