"""Sidebar ▸ ShapeSpace ▸ Live: source, port, status, Start/Stop, Calibrate, Record, takes."""
import math

import bpy

from ..bridge import live
from ..bridge.rig import live as rig_live
from .base import ShapeSpaceSidebar


class SHAPESPACE_UL_live_takes(bpy.types.UIList):
    """The file's live takes (actions carrying take metadata)."""

    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index=0):
        row = layout.row(align=True)
        info = live.take_info(item) if live.is_take(item) else {}
        mark = "" if info.get("complete", True) else " (interrupted)"
        row.label(text=f"{item.name}: {info.get('frames', 0)} frames{mark}", icon="ACTION")
        op = row.operator("shapespace.live_play_take", text="", icon="PLAY")
        op.take = item.name
        op = row.operator("shapespace.live_remove_take", text="", icon="X")
        op.take = item.name

    def filter_items(self, context, data, propname):
        items = getattr(data, propname)
        flags = [self.bitflag_filter_item if live.is_take(a) else 0 for a in items]
        return flags, []


class SHAPESPACE_PT_live(ShapeSpaceSidebar, bpy.types.Panel):
    """Stream a phone's face capture onto a rig, with head and eyes, calibration and recording"""

    bl_label = "Live"
    bl_idname = "SHAPESPACE_PT_live"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.layout
        st = context.scene.shapespace_live
        state = live.status()
        col = layout.column(align=True)
        col.enabled = not state.running
        row = col.row(align=True)
        row.prop(st, "source", text="")
        row.prop(st, "port", text="Port")
        col.prop(st, "address")
        col.prop(st, "target")
        col.prop(st, "method")
        if st.method == "SOLVE":
            col.prop(st, "template")
        elif st.method == "LEARNED":
            col.prop(st, "learn_csv")
            col.prop(st, "learn_action")
            col.prop(st, "key_pose_action")
        _draw_controls_hint(col, st, context.active_object)
        _draw_bones(layout, st, state.running)
        _draw_status(layout, state)
        _draw_takes(layout, st, state)


def _draw_controls_hint(col, st, active):
    """Offer Solve onto Controls when the target has a stored control set; say what is missing otherwise."""
    has = rig_live.has_controls(st.target or active)
    if st.method == rig_live.METHOD and not has:
        col.label(text="The target has no stored control set (Any Rig ▸ Controls)", icon="ERROR")
    elif has and st.method != rig_live.METHOD:
        col.label(text="The target has a control set: Solve onto Controls drives it", icon="INFO")


def _draw_bones(layout, st, running):
    box = layout.box()
    box.enabled = not running
    box.prop(st, "armature", icon="ARMATURE_DATA")
    if st.armature is not None and st.armature.type == "ARMATURE":
        for name in ("head_bone", "neck_bone", "eye_left_bone", "eye_right_bone"):
            box.prop_search(st, name, st.armature.data, "bones")
        box.prop(st, "neck_share")
    row = box.row(align=True)
    row.prop(st, "mirror")
    row.prop(st, "smoothing")
    if st.smoothing:
        row = box.row(align=True)
        row.prop(st, "min_cutoff")
        row.prop(st, "beta")


def _draw_status(layout, state):
    box = layout.box()
    row = box.row(align=True)
    if state.running:
        row.operator("shapespace.live_stop", icon="PAUSE")
        row.operator("shapespace.live_calibrate", icon="RESTRICT_SELECT_OFF")
    else:
        row.operator("shapespace.live_start", icon="PLAY")
    col = box.column(align=True)
    col.label(text=state.message, icon="INFO")
    if not state.running:
        return
    age = "–" if state.last_frame_age is None else f"{state.last_frame_age * 1000:.0f} ms"
    col.label(text=f"{state.packets_per_second:.0f} packets/s · last frame {age} ago")
    col.label(text=f"frames {state.frames} · dropped {state.dropped} · late {state.late} · "
                   f"malformed {state.malformed} · implausible {state.implausible}")
    if state.error:
        col.label(text=f"last refused: {state.error}", icon="ERROR")
    if not math.isnan(state.work_ms_p50):
        col.label(text=f"solve+write {state.work_ms_p50:.2f} ms (p99 {state.work_ms_p99:.2f}) · "
                       f"latency {state.latency_ms_p50:.1f} ms")
    if state.solver:
        col.label(text=state.solver, icon="ERROR" if state.budget_hits else "CON_ARMATURE")
    if state.calibrated:
        col.label(text="calibrated", icon="CHECKMARK")


def _draw_takes(layout, st, state):
    box = layout.box()
    row = box.row(align=True)
    row.prop(st, "take_name", text="")
    if state.recording:
        row.operator("shapespace.live_stop_recording", icon="SNAP_FACE")
        box.label(text=f"recording {state.take}: {state.take_frames} frames", icon="REC")
    else:
        sub = row.row(align=True)
        sub.enabled = state.running
        sub.operator("shapespace.live_record", icon="REC")
    row = box.row(align=True)
    row.prop(st, "clean_spacetime")
    row.prop(st, "clean_tolerance")
    box.template_list("SHAPESPACE_UL_live_takes", "", bpy.data, "actions", st, "active_take", rows=3)
