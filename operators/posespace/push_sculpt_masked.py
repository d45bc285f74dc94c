import bpy

from ...bridge.posespace import masked
from ..polls import psd_sculpt
from ..progress import window_progress
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_push_sculpt_masked(bpy.types.Operator):
    """Invert the active example's sculpt at the current pose and push it into one shape key per vertex-group
mask (normalised where masks overlap, so the keys add up to the sculpt), optionally with their mirrors"""

    bl_idname = "shapespace.push_sculpt_masked"
    bl_label = "Push Sculpt to Masked Keys"
    bl_options = {"REGISTER", "UNDO"}

    groups: bpy.props.StringProperty(name="Masks", description="Vertex groups to split by, comma-separated "
                                     "(e.g. Shoulder.L, Shoulder.R)")
    mirror: bpy.props.BoolProperty(name="Mirror", default=False,
                                   description="Also make every part's mirror (through the mesh's mirror map)")
    remainder: bpy.props.BoolProperty(name="Remainder", default=False,
                                      description="Put sculpted vertices no mask covers into <example>.remainder "
                                                  "(else they are refused, listed by index)")
    replace: bpy.props.BoolProperty(name="Replace", default=False,
                                    description="Overwrite keys of the same names from an earlier push")

    @classmethod
    def poll(cls, context):
        return psd_sculpt(cls, context, "push") is not None

    def invoke(self, context, event):
        return context.window_manager.invoke_props_dialog(self)

    def execute(self, context):
        ob = context.active_object
        st = ob.shapespace_psd
        name = st.examples[st.active_example].name
        groups = [g.strip() for g in self.groups.split(",") if g.strip()]
        with window_progress(context) as progress:
            made = attempt(self, masked.push_sculpt_masked, ob, name, groups, self.mirror, self.remainder,
                           replace=self.replace, progress=progress)
        if made is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"{name}: pushed into {', '.join(made)}")
        return {"FINISHED"}
