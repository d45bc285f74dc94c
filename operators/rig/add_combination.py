import bpy

from ...bridge import driven
from ..polls import sculpted_key
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_add_combination(bpy.types.Operator):
    """Make the active shape key a combination shape of 2–3 keys: it appears by the product of
their weights (driven natively: no Python at playback)"""

    bl_idname = "shapespace.add_combination"
    bl_label = "Add Combination"
    bl_options = {"REGISTER", "UNDO"}

    first: bpy.props.StringProperty(name="First")
    second: bpy.props.StringProperty(name="Second")
    third: bpy.props.StringProperty(name="Third", description="Optional")
    keep_source: bpy.props.BoolProperty(name="Keep Source Key", default=False)

    @classmethod
    def poll(cls, context):
        return sculpted_key(cls, context, "combination") is not None

    def invoke(self, context, event):
        return context.window_manager.invoke_props_dialog(self)

    def draw(self, context):
        keys = context.active_object.data.shape_keys
        for prop in ("first", "second", "third"):
            self.layout.prop_search(self, prop, keys, "key_blocks")
        self.layout.prop(self, "keep_source")

    def execute(self, context):
        ob = context.active_object
        inputs = [n for n in (self.first, self.second, self.third) if n]
        name = attempt(self, driven.add_combination, ob, inputs, ob.active_shape_key.name,
                       keep_source=self.keep_source)
        if name is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"Added combination {name}")
        return {"FINISHED"}
