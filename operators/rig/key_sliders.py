import bpy

from ...bridge import actions, shapekeys
from ..polls import active_rig


class SHAPESPACE_OT_key_sliders(bpy.types.Operator):
    """Insert a keyframe on every shape-key slider of the active mesh at the current frame"""

    bl_idname = "shapespace.key_sliders"
    bl_label = "Key All Sliders"
    bl_options = {"REGISTER", "UNDO"}

    only_changed: bpy.props.BoolProperty(
        name="Only Non-Zero", description="Key only sliders whose value is not zero", default=False)

    @classmethod
    def poll(cls, context):
        return active_rig(cls, context) is not None

    def execute(self, context):
        ob = context.active_object
        problems = [i for i in shapekeys.check_shape_keys(ob) if i.severity == "error"]
        if problems:
            self.report({"ERROR"}, problems[0].message)
            return {"CANCELLED"}
        names = shapekeys.slider_names(ob)
        count = actions.key_sliders(ob, names, context.scene.frame_current, self.only_changed)
        self.report({"INFO"}, f"Keyed {count} sliders at frame {context.scene.frame_current}")
        return {"FINISHED"}
