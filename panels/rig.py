import bpy

from ..bridge import symmetry
from .base import ShapeSpaceSidebar


class SHAPESPACE_PT_rig(ShapeSpaceSidebar, bpy.types.Panel):
    """The active mesh's shape-key rig and skin at a glance"""

    bl_label = "Rig"
    bl_idname = "SHAPESPACE_PT_rig"

    def draw(self, context):
        layout = self.layout
        ob = context.active_object
        if ob is None or ob.type != "MESH":
            layout.label(text="Select a mesh", icon="INFO")
            return
        col = layout.column(align=True)
        key = ob.data.shape_keys
        n_keys = len(key.key_blocks) - 1 if key else 0
        col.label(text=f"{ob.name}: {len(ob.data.vertices)} vertices", icon="MESH_DATA")
        col.label(text=f"{n_keys} shape keys" if n_keys else "No shape keys", icon="SHAPEKEY_DATA")
        arms = [m for m in ob.modifiers if m.type == "ARMATURE" and m.object]
        for m in arms:
            dq = " (Preserve Volume)" if m.use_deform_preserve_volume else ""
            col.label(text=f"{m.object.name}{dq}", icon="ARMATURE_DATA")
        row = layout.row(align=True)
        row.operator("shapespace.check_rig", icon="CHECKMARK")
        row.operator("shapespace.key_sliders", icon="KEY_HLT")
        _draw_symmetry(layout, ob)


def _draw_symmetry(layout, ob):
    """Rig ▸ Symmetry: the stored mirror map's state and the symmetry tools."""
    box = layout.box()
    box.label(text="Symmetry", icon="MOD_MIRROR")
    status = symmetry.map_status(ob)
    icon = {"ok": "CHECKMARK", "none": "INFO"}.get(status["state"], "ERROR")
    box.label(text=status["message"], icon=icon)
    box.operator("shapespace.build_mirror_map",
                 text="Rebuild Mirror Map" if status["state"] != "none" else "Build Mirror Map", icon="MOD_MIRROR")
    col = box.column(align=True)
    row = col.row(align=True)
    row.operator("shapespace.mirror_shape", icon="MOD_MIRROR")
    row.operator("shapespace.update_mirrored", icon="FILE_REFRESH")
    row = col.row(align=True)
    row.operator("shapespace.split_shape", icon="MOD_EDGESPLIT")
    row.operator("shapespace.combine_shapes", icon="AUTOMERGE_ON")
