import bpy

from ...bridge import posespace
from ...core.result import ShapeSpaceError
from ..polls import psd_mesh


class SHAPESPACE_OT_psd_bake_cache(bpy.types.Operator):
    """Bake the corrected mesh over a frame range to a PC2 point cache played by a Mesh Cache modifier
before the Armature modifier (every method, weighted PSD included; also for export)"""

    bl_idname = "shapespace.psd_bake_cache"
    bl_label = "Bake Point Cache"
    bl_options = {"REGISTER", "UNDO"}

    filepath: bpy.props.StringProperty(name="File", subtype="FILE_PATH",
                                       description="PC2 file (default: next to the .blend)")
    frame_start: bpy.props.IntProperty(name="Start", default=1)
    frame_end: bpy.props.IntProperty(name="End", default=250)

    @classmethod
    def poll(cls, context):
        return psd_mesh(cls, context, need_example=True) is not None

    def invoke(self, context, event):
        self.frame_start, self.frame_end = context.scene.frame_start, context.scene.frame_end
        return self.execute(context)

    def execute(self, context):
        ob = context.active_object
        if self.frame_end < self.frame_start:
            self.report({"ERROR"}, "the frame range is empty (end before start)")
            return {"CANCELLED"}
        try:
            path = posespace.cache_path(ob, self.filepath)
            posespace.bake_point_cache(ob, context.scene, self.frame_start, self.frame_end, path)
        except (ShapeSpaceError, OSError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, f"Baked frames {self.frame_start}–{self.frame_end} to {path}")
        return {"FINISHED"}
