import bpy

from ...bridge.rig import stored
from ..polls import control_face
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_set_control_bounds(bpy.types.Operator):
    """Override the bounds of one channel of the face's control set (unchecked: the rig's own bound — Limit
constraint, property range, slider range)"""

    bl_idname = "shapespace.set_control_bounds"
    bl_label = "Channel Bounds"
    bl_options = {"REGISTER", "UNDO"}

    index: bpy.props.IntProperty(name="Index", min=0)
    use_min: bpy.props.BoolProperty(name="Override Minimum")
    min: bpy.props.FloatProperty(name="Minimum")
    use_max: bpy.props.BoolProperty(name="Override Maximum")
    max: bpy.props.FloatProperty(name="Maximum")

    @classmethod
    def poll(cls, context):
        return control_face(cls, context) is not None

    def invoke(self, context, event):
        face = control_face(self, context)
        _, entries, problem = stored.status(face)
        if problem or not 0 <= self.index < len(entries):
            return self.execute(context)
        e = entries[self.index]
        self.use_min, self.use_max = e.lo is not None, e.hi is not None
        self.min = 0.0 if e.lo is None else e.lo
        self.max = 0.0 if e.hi is None else e.hi
        return context.window_manager.invoke_props_dialog(self)

    def execute(self, context):
        face = control_face(self, context)
        entry = attempt(self, stored.set_bounds, face, self.index, self.min if self.use_min else None,
                        self.max if self.use_max else None)
        if entry is FAILED:
            return {"CANCELLED"}
        lo, hi = ("rig's" if v is None else f"{v:g}" for v in (entry.lo, entry.hi))
        self.report({"INFO"}, f"{entry.label}: bounds {lo} to {hi}")
        return {"FINISHED"}
