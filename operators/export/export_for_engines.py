import os

import bpy

from ...bridge import export
from ..reporting import FAILED, attempt

FORMATS = (
    ("GLTF", "glTF (.glb)", "Morph targets with keyed weights, skeleton and correctives in one clip (engines)"),
    ("FBX", "FBX (.fbx)", "Shape-key animation FBX keeps (Unreal, Unity); skeleton and shape keys in one take"),
    ("ABC", "Alembic (.abc)", "The evaluated mesh per frame: exact for every deformer, weighted PSD included"),
)
EXTENSIONS = {"GLTF": ".glb", "FBX": ".fbx", "ABC": ".abc"}


def exportable_selection(cls, context):
    """The selected meshes and armatures; otherwise say why and return None."""
    chosen = [ob for ob in context.selected_objects if ob.type in export.EXPORTED_TYPES]
    if not chosen:
        cls.poll_message_set("Select a mesh (shape keys, skin) or an armature to export")
        return None
    editing = [ob for ob in chosen if ob.mode == "EDIT"]
    if editing:
        cls.poll_message_set(f"'{editing[0].name}' is in Edit Mode: leave Edit Mode first (its mesh data is not "
                             "up to date until then)")
        return None
    return chosen


class SHAPESPACE_OT_export_for_engines(bpy.types.Operator):
    """Export the selection for game engines and other tools: shape-key animation, in-between and combination
drivers and pose-space correctives are baked into data glTF, FBX or Alembic carry (the file is not changed)"""

    bl_idname = "shapespace.export_for_engines"
    bl_label = "Export for Engines"
    bl_options = {"REGISTER"}

    filepath: bpy.props.StringProperty(name="File", subtype="FILE_PATH", options={"SKIP_SAVE"})
    format: bpy.props.EnumProperty(name="Format", items=FORMATS, default="GLTF")
    use_frame_range: bpy.props.BoolProperty(
        name="Frame Range", default=False,
        description="Bake only these frames (off: the full range of the exported objects' actions)")
    frame_start: bpy.props.IntProperty(name="Start", default=1)
    frame_end: bpy.props.IntProperty(name="End", default=250)
    filter_glob: bpy.props.StringProperty(default="*.glb;*.gltf;*.fbx;*.abc", options={"HIDDEN"})

    @classmethod
    def poll(cls, context):
        return exportable_selection(cls, context) is not None

    def check(self, context):
        """Keep the file extension in step with the format (the file browser calls this)."""
        ext = EXTENSIONS[self.format]
        base, old = os.path.splitext(self.filepath)
        if self.filepath and old.lower() != ext and not (self.format == "GLTF" and old.lower() == ".gltf"):
            self.filepath = base + ext
            return True
        return False

    def invoke(self, context, event):
        if not self.filepath:
            stem = os.path.splitext(bpy.path.basename(bpy.data.filepath))[0] or "untitled"
            self.filepath = os.path.join(os.path.dirname(bpy.data.filepath) or os.getcwd(),
                                         stem + EXTENSIONS[self.format])
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        frame_range = (self.frame_start, self.frame_end) if self.use_frame_range else None
        rep = attempt(self, export.export, self.format.lower(), bpy.path.abspath(self.filepath),
                      frame_range=frame_range)
        if rep is FAILED:
            return {"CANCELLED"}
        for note in rep.notes:
            self.report({"WARNING"}, note)
        what = f"frames {rep.frame_start}–{rep.frame_end}" if rep.animated else f"frame {rep.frame_start}"
        self.report({"INFO"}, f"Exported {', '.join(rep.objects)} ({what}) to {rep.path}")
        return {"FINISHED"}
