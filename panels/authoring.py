"""Sidebar ▸ ShapeSpace ▸ Rig ▸ Transfer Shapes: model transfer of a source rig's shapes onto the active mesh."""
import bpy

from ..bridge import authoring
from .base import ShapeSpaceSidebar

SHOWN = 12          # landmark pairs listed in the panel


class SHAPESPACE_PT_transfer_shapes(ShapeSpaceSidebar, bpy.types.Panel):
    """Give the active mesh a source rig's shape keys (landmarks, registration preview, then transfer)"""

    bl_label = "Transfer Shapes"
    bl_idname = "SHAPESPACE_PT_transfer_shapes"
    bl_parent_id = "SHAPESPACE_PT_rig"
    bl_options = {"DEFAULT_CLOSED"}

    @classmethod
    def poll(cls, context):
        ob = context.active_object
        return ob is not None and ob.type == "MESH"

    def draw(self, context):
        layout = self.layout
        ob = context.active_object
        st = ob.shapespace_authoring
        col = layout.column(align=True)
        col.prop(st, "source")
        col.prop(st, "naming")
        col.prop(st, "existing")
        col.prop(st, "unmatched_parts")
        col.prop(st, "parts_collection")
        box = layout.box()
        n, problem = authoring.landmark_count(ob)
        enough = n >= authoring.MIN_LANDMARKS
        text = f"Landmarks: {n} pairs" + ("" if enough else f" (at least {authoring.MIN_LANDMARKS})")
        box.label(text=problem or text, icon="PIVOT_CURSOR" if enough and not problem else "ERROR")
        pairs = authoring.landmark_list(ob)
        col = box.column(align=True)
        for i, (a, b) in enumerate(pairs[:SHOWN]):
            row = col.row(align=True)
            row.label(text=f"{i + 1}: source {a} ↔ target {b}")
            op = row.operator("shapespace.remove_landmark_pair", text="", icon="X")
            op.index = i
        if len(pairs) > SHOWN:
            col.label(text=f"… and {len(pairs) - SHOWN} more")
        row = box.row(align=True)
        row.operator("shapespace.propose_landmarks", icon="AUTO")
        row.operator("shapespace.clear_landmark_pairs", text="", icon="TRASH")
        box.operator("shapespace.add_landmark_pair", text="Add Selected Vertex Pair", icon="ADD")
        row = layout.row(align=True)
        row.operator("shapespace.preview_registration", icon="HIDE_OFF")
        row.operator("shapespace.clear_registration_preview", text="", icon="X")
        layout.operator("shapespace.transfer_shapes", icon="SHAPEKEY_DATA")
