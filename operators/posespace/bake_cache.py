import os

import bpy

from ...bridge import posespace
from ...core.result import ShapeSpaceError
from ..polls import psd_mesh
from ..progress import window_progress


class SHAPESPACE_OT_psd_bake_cache(bpy.types.Operator):
    """Bake the corrected mesh over a frame range to a PC2 point cache played by a Mesh Cache modifier
before the Armature modifier (every method, weighted PSD included; also for export)"""

    bl_idname = "shapespace.psd_bake_cache"
    bl_label = "Bake Point Cache"
    bl_options = {"REGISTER", "UNDO"}

    filename_ext = ".pc2"
    filepath: bpy.props.StringProperty(
        name="File", subtype="FILE_PATH",
        description="PC2 file (default: <object>_correctives.pc2 next to the saved .blend); stored relative "
                    "to the .blend when it is saved and the Relative Paths preference is on")
    filter_glob: bpy.props.StringProperty(default="*.pc2", options={"HIDDEN"})
    overwrite: bpy.props.BoolProperty(
        name="Overwrite", default=False,
        description="Replace an existing file that is not this mesh's point cache")
    frame_start: bpy.props.IntProperty(name="Start", default=1)
    frame_end: bpy.props.IntProperty(name="End", default=250)

    @classmethod
    def poll(cls, context):
        return psd_mesh(cls, context, need_example=True) is not None

    def invoke(self, context, event):
        """Open the file browser at the default cache file (next to the saved .blend)."""
        self.frame_start, self.frame_end = context.scene.frame_start, context.scene.frame_end
        if not self.filepath:
            name = posespace.default_cache_name(context.active_object)
            folder = os.path.dirname(bpy.data.filepath) if bpy.data.filepath else ""
            self.filepath = os.path.join(folder, name) if folder else name
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def check(self, context):
        """Give the chosen file the .pc2 extension (the file browser calls this)."""
        if self.filepath and not self.filepath.lower().endswith(self.filename_ext) and \
                not os.path.isdir(bpy.path.abspath(self.filepath)):
            self.filepath = bpy.path.ensure_ext(self.filepath, self.filename_ext)
            return True
        return False

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
        stored = posespace.stored_cache_path(path)
        how = "relative to the .blend" if stored.startswith("//") else (
            "absolute: save the file to store it relative" if not bpy.data.filepath else "absolute")
        self.report({"INFO"}, f"Baked frames {self.frame_start}–{self.frame_end} to {stored} ({how})")
        return {"FINISHED"}
