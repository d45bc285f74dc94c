import bpy

from ...bridge import driven
from ..polls import sculpted_key
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_add_inbetween(bpy.types.Operator):
    """Make the active shape key an in-between of another key at a given weight
(piecewise-linear, driven natively: no Python at playback)"""

    bl_idname = "shapespace.add_inbetween"
    bl_label = "Add In-Between"
    bl_options = {"REGISTER", "UNDO"}

    primary: bpy.props.StringProperty(name="Primary", description="The key this shape is an in-between of")
    weight: bpy.props.FloatProperty(name="At Weight", default=0.5, min=0.01, max=0.99)
    keep_source: bpy.props.BoolProperty(name="Keep Source Key", default=False)

    @classmethod
    def poll(cls, context):
        return sculpted_key(cls, context, "in-between") is not None

    def invoke(self, context, event):
        return context.window_manager.invoke_props_dialog(self)

    def draw(self, context):
        self.layout.prop_search(self, "primary", context.active_object.data.shape_keys, "key_blocks")
        self.layout.prop(self, "weight")
        self.layout.prop(self, "keep_source")

    def execute(self, context):
        ob = context.active_object
        name = attempt(self, driven.add_inbetween, ob, self.primary, ob.active_shape_key.name, self.weight,
                       keep_source=self.keep_source)
        if name is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"Added in-between {name}")
        return {"FINISHED"}
