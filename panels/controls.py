"""Rig ▸ Controls: the face's stored control set (issue #25) — its channels with bounds and enabled toggles, and
the verbs that propose, add, remove, clear and mirror them.  Draws the active mesh's set, or with an armature
active (Pose Mode) the set of the face it drives; damaged data is named, never drawn through."""
import math

import bpy

from ..bridge.rig import stored
from ..core.result import ShapeSpaceError
from .base import ShapeSpaceSidebar

#: Channels shown per page.
PAGE = 20


def _bounds_text(entry, channel) -> str:
    """``[lo, hi]`` as the solve uses them; an override is marked with *."""
    if channel is None:
        return "?"

    def one(v, override):
        text = "−∞" if v == -math.inf else "∞" if v == math.inf else f"{v:.3g}"
        return text + ("*" if override is not None else "")
    return f"[{one(channel.lo, entry.lo)}, {one(channel.hi, entry.hi)}]"


def _channel(entry):
    """The rig's channel for an entry, or None when the rig no longer has it (its row says so)."""
    try:
        return stored.to_channel(entry)
    except ShapeSpaceError:
        return None


class SHAPESPACE_PT_controls(ShapeSpaceSidebar, bpy.types.Panel):
    """The face's control set: the channels a capture is retargeted onto (`retarget --controls stored`) on a bone-,
driver- or hybrid-rigged face"""

    bl_label = "Controls"
    bl_idname = "SHAPESPACE_PT_controls"
    bl_parent_id = "SHAPESPACE_PT_rig"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.layout
        try:
            face = stored.face_for(context.active_object, context.selected_objects)
        except ShapeSpaceError as exc:
            layout.label(text=str(exc), icon="INFO")
            return
        armature, entries, problem = stored.status(face)
        col = layout.column(align=True)
        row = col.row(align=True)
        row.operator("shapespace.propose_controls", icon="VIEWZOOM")
        row.operator("shapespace.mirror_controls", icon="MOD_MIRROR")
        row = col.row(align=True)
        row.operator("shapespace.add_control_bones", icon="BONE_DATA")
        row.operator("shapespace.add_control_property", icon="PROPERTIES")
        if problem:
            layout.label(text=problem, icon="ERROR")
            layout.operator("shapespace.clear_controls", icon="TRASH")
            return
        if not entries:
            layout.label(text=f"{face.name}: no control set stored", icon="INFO")
            return
        enabled = sum(e.enabled for e in entries)
        head = f"{face.name}: {len(entries)} channels, {enabled} enabled"
        layout.label(text=head + (f" ({armature})" if armature else ""), icon="DRIVER")
        _draw_rows(layout, context, entries)
        layout.operator("shapespace.clear_controls", icon="TRASH")


def _draw_rows(layout, context, entries) -> None:
    wm = context.window_manager
    pages = max(1, math.ceil(len(entries) / PAGE))
    page = min(wm.shapespace_controls_page, pages - 1)
    if pages > 1:
        row = layout.row()
        row.prop(wm, "shapespace_controls_page", text=f"Page (of {pages})")
    box = layout.box()
    col = box.column(align=True)
    for i in range(page * PAGE, min(len(entries), (page + 1) * PAGE)):
        e = entries[i]
        ch = _channel(e)
        row = col.row(align=True)
        op = row.operator("shapespace.toggle_control", text="", emboss=False,
                          icon="CHECKBOX_HLT" if e.enabled else "CHECKBOX_DEHLT")
        op.index, op.enabled = i, not e.enabled
        row.label(text=e.label, icon="ERROR" if ch is None else "NONE")
        row.label(text=_bounds_text(e, ch))
        op = row.operator("shapespace.set_control_bounds", text="", icon="PREFERENCES")
        op.index = i
        op = row.operator("shapespace.remove_control", text="", icon="X")
        op.index = i
