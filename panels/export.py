import bpy

from .base import ShapeSpaceSidebar


class SHAPESPACE_PT_export(ShapeSpaceSidebar, bpy.types.Panel):
    """Export for engines: glTF, FBX and Alembic with drivers and pose-space correctives baked"""

    bl_label = "Export"
    bl_idname = "SHAPESPACE_PT_export"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.layout
        chosen = [ob for ob in context.selected_objects if ob.type in ("MESH", "ARMATURE")]
        col = layout.column(align=True)
        if chosen:
            col.label(text=f"{len(chosen)} selected: {', '.join(ob.name for ob in chosen[:3])}"
                      + ("…" if len(chosen) > 3 else ""), icon="EXPORT")
        else:
            col.label(text="Select a mesh or an armature", icon="INFO")
        row = layout.row(align=True)
        for fmt, text in (("GLTF", "glTF"), ("FBX", "FBX"), ("ABC", "Alembic")):
            op = row.operator("shapespace.export_for_engines", text=text)
            op.format = fmt
        layout.label(text="Bakes drivers and correctives; the file is not changed", icon="CHECKMARK")
