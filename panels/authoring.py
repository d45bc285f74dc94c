"""Sidebar ▸ ShapeSpace ▸ Rig ▸ Transfer Shapes: model transfer of a source rig's shapes onto the active mesh."""
from collections import Counter

import bpy

from ..bridge import authoring
from .base import ShapeSpaceSidebar

SHOWN = 12          # landmark pairs listed in the panel


class SHAPESPACE_UL_transfer_examples(bpy.types.UIList):
    """Shape keys of the target given as examples of the source rig's shapes"""

    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index):
        row = layout.row(align=True)
        key = context.active_object.data.shape_keys
        there = key is not None and item.key in key.key_blocks
        row.label(text=item.key, icon="SHAPEKEY_DATA" if there else "ERROR")
        row.prop(item, "weights", text="")


class SHAPESPACE_UL_transfer_parts(bpy.types.UIList):
    """The target's facial parts: mesh and lowest vertex, size, the kind used last and the kind set"""

    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index):
        row = layout.row(align=True)
        stale = item.used == ""
        row.label(text=f"{item.object or data.id_data.name} #{item.vertex} ({item.vertices})",
                  icon="ERROR" if stale else "QUESTION" if item.unsure else "MESH_DATA")
        row.label(text=item.used or "gone")
        row.prop(item, "kind", text="")


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
        _draw_parts(layout, ob)
        _draw_examples(layout, ob)
        row = layout.row(align=True)
        row.operator("shapespace.preview_registration", icon="HIDE_OFF")
        row.operator("shapespace.clear_registration_preview", text="", icon="X")
        layout.operator("shapespace.transfer_shapes", icon="SHAPEKEY_DATA")
        _draw_verdict(layout, ob)


def _draw_examples(layout, ob) -> None:
    """The examples: shape keys of this mesh, each with its weights of the source's shapes."""
    box = layout.box()
    st = ob.shapespace_authoring
    box.label(text=f"Examples: {len(st.examples)}" if len(st.examples) else "Examples: none (plain transfer)",
              icon="SHAPEKEY_DATA")
    row = box.row()
    row.template_list("SHAPESPACE_UL_transfer_examples", "", st, "examples", st, "active_example", rows=2)
    col = row.column(align=True)
    col.operator("shapespace.add_transfer_example", text="", icon="ADD")
    col.operator("shapespace.remove_transfer_example", text="", icon="REMOVE")


def _draw_parts(layout, ob) -> None:
    """The parts: each with the kind the last Find Parts or transfer used (why, for the active one) and the kind
    the user set."""
    box = layout.box()
    st = ob.shapespace_authoring
    unsure = sum(row.unsure for row in st.parts)
    text = f"Parts: {len(st.parts)}" + (f", {unsure} unsure" if unsure else "") if len(st.parts) else \
        "Parts: not listed yet (Find Parts)"
    box.label(text=text, icon="MESH_DATA")
    if len(st.parts):
        row = box.row()
        row.template_list("SHAPESPACE_UL_transfer_parts", "", st, "parts", st, "active_part", rows=3)
        if 0 <= st.active_part < len(st.parts):
            box.label(text=st.parts[st.active_part].reason or "-", icon="INFO")
    row = box.row(align=True)
    row.operator("shapespace.find_transfer_parts", icon="VIEWZOOM")
    row.operator("shapespace.select_transfer_part", text="", icon="RESTRICT_SELECT_OFF")


def _draw_verdict(layout, ob) -> None:
    """The last transfer's checks: status, the keys that failed a check, the parts and their kinds."""
    verdict, problem = authoring.verdict_status(ob)
    if problem:
        layout.label(text=problem, icon="ERROR")
    if verdict is None:
        return
    box = layout.box()
    ok = verdict["status"] == "ok"
    box.label(text=f"Last transfer from {verdict['source']}: " + ("every key passed its checks" if ok else
              f"{len(verdict['failed'])} keys failed a check"), icon="CHECKMARK" if ok else "ERROR")
    col = box.column(align=True)
    for name, checks in verdict["failed"][:SHOWN]:
        col.label(text=f"{name}: {', '.join(checks)}")
    if len(verdict["failed"]) > SHOWN:
        col.label(text=f"… and {len(verdict['failed']) - SHOWN} more")
    kinds = Counter(kind for _, kind, _, _ in verdict["parts"])
    if kinds:
        box.label(text="Parts: " + ", ".join(f"{n} {k}" for k, n in sorted(kinds.items())), icon="MESH_DATA")
    unsure = [str(p) for p, _, _, flag in verdict["parts"] if flag]
    if unsure:
        box.label(text=f"Check the kind of part {', '.join(unsure[:8])}", icon="QUESTION")
    if verdict["openings"]:
        box.label(text="Openings: " + ", ".join(verdict["openings"]), icon="HIDE_OFF")
