import bpy

from ...bridge.posespace import postdeform
from ...core.result import Status
from ..polls import psd_sculpt
from ..reporting import FAILED
from ._apply import apply_active_sculpt


class SHAPESPACE_OT_apply_post_deform(bpy.types.Operator):
    """Store the active example's sculpt as a post-deformation corrective: offsets in a frame of the deformed
surface, added after the armature by a generated Geometry Nodes modifier (plays without the add-on, survives
re-weighting without re-inversion)"""

    bl_idname = "shapespace.apply_post_deform"
    bl_label = "Apply as Post-Deformation"
    bl_options = {"REGISTER", "UNDO"}

    remove_copy: bpy.props.BoolProperty(name="Remove Posed Copy", default=False,
                                        description="Delete the sculpt copy once applied")

    @classmethod
    def poll(cls, context):
        return psd_sculpt(cls, context) is not None

    def execute(self, context):
        applied = apply_active_sculpt(self, context, postdeform.apply_post_deform)
        if applied is FAILED:
            return {"CANCELLED"}
        _, name, result = applied
        level = {"INFO"} if result.status == Status.OK else {"WARNING"}
        self.report(level, f"{name}: post-deformation corrective stored (modifier '{postdeform.MODIFIER}')")
        return {"FINISHED"}
