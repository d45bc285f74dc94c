"""Sidebar ▸ ShapeSpace ▸ Rig ▸ Transfer Shapes ▸ Named Landmarks: guided placement, one name at a time."""
import bpy

from ..bridge import named_landmarks as named
from ..core.authoring.named import NAMES, mirror_name
from .base import ShapeSpaceSidebar


class SHAPESPACE_PT_named_landmarks(ShapeSpaceSidebar, bpy.types.Panel):
    """Named landmarks of the active mesh (eye and mouth corners, lids, lips, nose, chin, brows, jaw): select a
vertex and place the next name; mirror the placed ones; use them for the transfer"""

    bl_label = "Named Landmarks"
    bl_idname = "SHAPESPACE_PT_named_landmarks"
    bl_parent_id = "SHAPESPACE_PT_transfer_shapes"
    bl_options = {"DEFAULT_CLOSED"}

    @classmethod
    def poll(cls, context):
        ob = context.active_object
        return ob is not None and ob.type == "MESH"

    def draw(self, context):
        layout = self.layout
        ob = context.active_object
        marks, problem = named.named_status(ob)
        if problem:
            layout.label(text=problem, icon="ERROR")
        nxt = next((n for n in NAMES if n not in marks), None)
        layout.label(text=f"{len(marks)} of {len(NAMES)} placed", icon="PIVOT_CURSOR")
        if nxt is not None:
            partner = mirror_name(nxt)
            hint = f" (then Mirror fills {partner})" if partner != nxt else ""
            layout.label(text=f"Next: {nxt}{hint}")
            layout.operator("shapespace.place_named_landmark", text=f"Place {nxt} at Selected Vertex", icon="ADD")
        row = layout.row(align=True)
        row.operator("shapespace.mirror_named_landmarks", icon="MOD_MIRROR")
        row.operator("shapespace.clear_named_landmarks", text="", icon="TRASH")
        col = layout.column(align=True)
        for n in NAMES:
            if n in marks:
                row = col.row(align=True)
                row.label(text=f"{n}: vertex {marks[n]}")
                op = row.operator("shapespace.place_named_landmark", text="", icon="RESTRICT_SELECT_OFF")
                op.name = n
        layout.operator("shapespace.use_named_landmarks", icon="LINKED")
