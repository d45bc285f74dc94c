import bpy

from ...bridge import retarget
from ..polls import active_rig
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_suggest_key_poses(bpy.types.Operator):
    """Mark the source performance's most telling frames on the timeline ("key pose" markers): pose this rig
at each and key it, then retarget with the Learned method (Chuang–Bregler key poses)"""

    bl_idname = "shapespace.suggest_key_poses"
    bl_label = "Suggest Key Poses"
    bl_options = {"REGISTER", "UNDO"}

    filepath: bpy.props.StringProperty(name="CSV File", subtype="FILE_PATH")
    action: bpy.props.StringProperty(name="Action")
    count: bpy.props.IntProperty(name="Poses", default=0, min=0,
                                 description="How many (0: one per moving source channel, plus two)")

    @classmethod
    def poll(cls, context):
        return active_rig(cls, context) is not None

    def execute(self, context):
        source = bpy.path.abspath(self.filepath) if self.filepath else self.action
        if not source:
            self.report({"ERROR"}, "choose a CSV file or an action as the source")
            return {"CANCELLED"}
        frames = attempt(self, retarget.suggest_key_poses, source, context.scene, self.count or None)
        if frames is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"{len(frames)} key poses marked on the timeline")
        return {"FINISHED"}
