import bpy

from ...bridge import retarget
from ..polls import active_rig
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_set_mapping(bpy.types.Operator):
    """Map a source channel to one of this rig's shape keys with a gain and an offset (stored in the file)"""

    bl_idname = "shapespace.set_mapping"
    bl_label = "Set Channel Mapping"
    bl_options = {"REGISTER", "UNDO"}

    source: bpy.props.StringProperty(name="Source Channel", description="e.g. JawOpen")
    target: bpy.props.StringProperty(name="Target Key", description="Shape key of this mesh")
    gain: bpy.props.FloatProperty(name="Gain", default=1.0)
    offset: bpy.props.FloatProperty(name="Offset", default=0.0)

    @classmethod
    def poll(cls, context):
        return active_rig(cls, context) is not None

    def execute(self, context):
        ob = context.active_object
        if attempt(self, retarget.set_mapping, ob, self.source, self.target, self.gain, self.offset) is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"{self.source} → {self.target} × {self.gain:g} + {self.offset:g}")
        return {"FINISHED"}
