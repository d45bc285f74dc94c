import bpy

from ..bridge.rig import tool
from .base import ShapeSpaceSidebar, shape_key_mesh


class SHAPESPACE_UL_pins(bpy.types.UIList):
    """Pins of the active mesh"""

    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index):
        kind = "Stationary" if item.stationary else "Pin"
        link = item.mirror_of
        mirror = "" if link < 0 else (" · centre" if link == index else f" ↔ {link}")
        layout.label(text=f"{kind} {index}: vertex {item.vertices[0]}{mirror}",
                     icon="PINNED" if item.stationary else "UNPINNED")


class SHAPESPACE_PT_direct(ShapeSpaceSidebar, bpy.types.Panel):
    """Pin-and-drag direct manipulation of the shape-key sliders"""

    bl_label = "Direct Manipulation"
    bl_idname = "SHAPESPACE_PT_direct"

    @classmethod
    def poll(cls, context):
        return shape_key_mesh(context) or tool.uses_rig(context.active_object)

    def draw(self, context):
        layout = self.layout
        st = context.active_object.shapespace
        rig = tool.uses_rig(context.active_object)       # dragged through its control set: α, prior, Symmetric
        keys = shape_key_mesh(context)
        layout.row().prop(st, "mode", expand=True)
        if st.mode == "SLIDERS":
            layout.label(text="Animate with the Shape Keys sliders", icon="INFO")
            return
        col = layout.column(align=True)
        col.prop(st, "alpha")
        if not rig:
            col.prop(st, "mu")
        if st.mode == "LEARNED":
            box = layout.box()
            box.prop(st, "prior_action")
            row = box.row(align=True)
            row.prop(st, "prior_start")
            row.prop(st, "prior_end")
            if not rig:
                box.prop(st, "prior_form")
                box.prop(st, "snap")
        row = layout.row(align=True)
        row.prop(st, "symmetric", icon="MOD_MIRROR")
        if keys:
            row.operator("shapespace.mirror_pins", icon="MOD_MIRROR", text="Mirror Pins")
        layout.label(text="Pin tool: click and drag on the face", icon="RESTRICT_SELECT_OFF")
        layout.template_list("SHAPESPACE_UL_pins", "", st, "pins", st, "active_pin", rows=3)
        row = layout.row(align=True)
        if not rig:
            row.operator("shapespace.solve_pins", icon="PLAY")
        row.operator("shapespace.remove_pin", icon="REMOVE", text="")
        row.operator("shapespace.clear_pins", icon="X", text="")
        if not keys:
            return
        row = layout.row(align=True)
        row.operator("shapespace.add_inbetween", icon="IPO_LINEAR")
        row.operator("shapespace.add_combination", icon="AUTOMERGE_OFF")
