import bpy

from ...bridge import posespace
from ...core.result import ShapeSpaceError
from ..polls import psd_mesh
from .progress import window_progress


class SHAPESPACE_OT_psd_bake_cache(bpy.types.Operator):
    """Bake the corrected mesh over a frame range to a PC2 point cache played by a Mesh Cache modifier
before the Armature modifier (every method, weighted PSD included; also for export)"""

    bl_idname = "shapespace.psd_bake_cache"
    bl_label = "Bake Point Cache"
    bl_options = {"REGISTER", "UNDO"}

    filepath: bpy.props.StringProperty(
        name="File", subtype="FILE_PATH",
        description="PC2 file (default: <object>_correctives.pc2 next to the saved .blend)")
    overwrite: bpy.props.BoolProperty(
        name="Overwrite", default=False,
        description="Replace an existing file that is not this mesh's point cache")
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
            path = posespace.cache_path(ob, self.filepath, self.overwrite)
            with window_progress(context) as progress:
                posespace.bake_point_cache(ob, context.scene, self.frame_start, self.frame_end, path,
                                           progress=progress)
        except (ShapeSpaceError, OSError) as exc:
            self.report({"ERROR"}, str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
            return {"CANCELLED"}
        self.report({"INFO"}, f"Baked frames {self.frame_start}–{self.frame_end} to {path}")
        return {"FINISHED"}
