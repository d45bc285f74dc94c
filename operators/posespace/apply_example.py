import bpy

from ...bridge import posespace
from ...core.result import Status
from ..polls import psd_sculpt
from ..reporting import FAILED, report_issues
from ._apply import apply_active_sculpt


class SHAPESPACE_OT_psd_apply_example(bpy.types.Operator):
    """Store the active example's sculpt as a rest-space corrective (inverting the skinning at its pose)"""

    bl_idname = "shapespace.psd_apply_example"
    bl_label = "Apply Sculpt"
    bl_options = {"REGISTER", "UNDO"}

    remove_copy: bpy.props.BoolProperty(name="Remove Posed Copy", default=False,
                                        description="Delete the sculpt copy once applied")

    @classmethod
    def poll(cls, context):
        return psd_sculpt(cls, context) is not None

    def execute(self, context):
        applied = apply_active_sculpt(self, context, posespace.apply_example)
        if applied is FAILED:
            return {"CANCELLED"}
        ob, name, result = applied
        report_issues(self, posespace.flag_examples(ob))
        level = {"INFO"} if result.status == Status.OK else {"WARNING"}
        self.report(level, f"{name}: {result.message} (largest error {result.residual:.3g})")
        return {"FINISHED"}
