"""Transfer Shapes ▸ Examples: list the active shape key as an example of the source's shapes, or remove one."""
import bpy

from ...bridge import authoring
from ..polls import sculpted_key
from ..reporting import FAILED, attempt
from ._polls import listed


class SHAPESPACE_OT_add_transfer_example(bpy.types.Operator):
    """List the active shape key as an example: Transfer Shapes refines every key so it is reproduced (give its
weights of the source's shapes unless it is named after one)"""

    bl_idname = "shapespace.add_transfer_example"
    bl_label = "Add Example"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return sculpted_key(cls, context, "example") is not None

    def execute(self, context):
        name = attempt(self, authoring.add_example, context.active_object)
        if name is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"{name!r} is an example of the transfer")
        return {"FINISHED"}


class SHAPESPACE_OT_remove_transfer_example(bpy.types.Operator):
    """Remove an example from the list (the shape key itself stays)"""

    bl_idname = "shapespace.remove_transfer_example"
    bl_label = "Remove Example"
    bl_options = {"REGISTER", "UNDO"}

    index: bpy.props.IntProperty(name="Index", default=-1, min=-1, description="Example to remove; −1: the active")

    @classmethod
    def poll(cls, context):
        return listed(cls, context, "examples", "The mesh has no examples") is not None

    def execute(self, context):
        ob = context.active_object
        index = self.index if self.index >= 0 else ob.shapespace_authoring.active_example
        name = attempt(self, authoring.remove_example, ob, index)
        if name is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"{name!r} is no longer an example")
        return {"FINISHED"}
