import bpy

from ..bridge import retarget
from ..bridge.rig import last_take, stored
from ..core.result import ShapeSpaceError
from ..core.retarget.report import format_ranges
from .base import ShapeKeyPanel


class SHAPESPACE_PT_retarget(ShapeKeyPanel, bpy.types.Panel):
    """Retarget captures, actions and mesh performances onto this rig"""

    bl_label = "Retarget"
    bl_idname = "SHAPESPACE_PT_retarget"

    def draw(self, context):
        layout = self.layout
        ob = context.active_object
        st = ob.shapespace_retarget
        layout.row().prop(st, "target", expand=True)
        if st.target == "CONTROLS":
            _draw_onto_controls(layout, ob, st)
            return
        layout.prop(st, "source_kind", text="")
        source = {"CSV": "csv_path", "ACTION": "action", "MESH": "source_object"}[st.source_kind]
        layout.prop(st, source, text="")
        col = layout.column(align=True)
        col.prop(st, "method", text="Method")
        if st.method == "learned":
            row = col.row(align=True)
            row.prop(st, "key_pose_action", text="")
            op = row.operator("shapespace.suggest_key_poses", text="", icon="MARKER_HLT")
            op.filepath = bpy.path.abspath(st.csv_path) if st.source_kind == "CSV" else ""
            op.action = st.action.name if st.source_kind == "ACTION" and st.action else ""
        col.prop(st, "key_tolerance")
        if st.key_tolerance > 0:
            col.prop(st, "key_shape", text="Keys")
        col.prop(st, "extend_scene_range")
        op = layout.operator("shapespace.retarget", icon="ACTION")
        op.method, op.key_tolerance, op.key_shape = st.method, st.key_tolerance, st.key_shape
        op.extend_scene_range = st.extend_scene_range
        op.filepath = bpy.path.abspath(st.csv_path) if st.source_kind == "CSV" else ""
        op.action = st.action.name if st.source_kind == "ACTION" and st.action else ""
        op.source_object = st.source_object.name if st.source_kind == "MESH" and st.source_object else ""
        op.key_pose_action = st.key_pose_action.name if st.key_pose_action else ""
        if st.source_kind == "CSV":
            _draw_bones(layout, st, op)

        _draw_result(layout, ob)
        _draw_mapping(layout, ob)
        _draw_landmarks(layout, ob, st)


def _draw_onto_controls(layout, ob, st):
    """The route onto the face's stored control set: a recording or a shape-key action, per frame, its last result."""
    _armature, entries, problem = stored.status(ob)
    if problem:
        layout.label(text=problem, icon="ERROR")
    elif not entries:
        layout.label(text="No control set: propose or add one (Rig ▸ Controls)", icon="INFO")
    else:
        layout.label(text=f"{sum(e.enabled for e in entries)} enabled controls", icon="BONE_DATA")
    layout.prop(st, "source_kind", text="")
    if st.source_kind == "MESH":
        layout.label(text="Onto rig controls: capture recordings and shape-key actions only", icon="ERROR")
        return
    layout.prop(st, "csv_path" if st.source_kind == "CSV" else "action", text="")
    col = layout.column(align=True)
    col.label(text="Method: per frame (space-time and cloning: retarget --controls on the command line)")
    col.prop(st, "rig_key_tolerance")
    op = layout.operator("shapespace.retarget_controls", icon="ACTION")
    op.filepath = bpy.path.abspath(st.csv_path) if st.source_kind == "CSV" else ""
    op.action = st.action.name if st.source_kind == "ACTION" and st.action else ""
    op.key_tolerance = st.rig_key_tolerance
    try:
        result = last_take.summary_of(ob)
    except ShapeSpaceError as exc:          # damaged stored data: say so, never fail the draw
        layout.label(text=str(exc), icon="ERROR")
        return
    if result:
        box = layout.box()
        for part in result.split("; "):
            box.label(text=part)
        box.operator("shapespace.discard_retarget", icon="LOOP_BACK").result = "CONTROLS"


def _draw_bones(layout, st, op):
    """The head, neck and eye bones a recording's head and eye channels key (as live capture drives them)."""
    box = layout.box()
    box.label(text="Head & Eyes (from the recording)", icon="BONE_DATA")
    box.prop(st, "armature")
    arm = st.armature if st.armature is not None and st.armature.type == "ARMATURE" else None
    if arm is not None:
        for name in ("head_bone", "neck_bone", "eye_left_bone", "eye_right_bone"):
            box.prop_search(st, name, arm.data, "bones")
        if st.neck_bone:
            box.prop(st, "neck_share")
        box.prop(st, "mirror")
        row = box.row()
        row.prop(st, "calibrate")
        row.prop(st, "rest_frame")
    if arm is None:
        return
    op.armature, op.neck_share, op.mirror = arm.name, st.neck_share, st.mirror
    op.calibrate, op.rest_frame = st.calibrate, st.rest_frame
    op.head_bone, op.neck_bone = st.head_bone, st.neck_bone
    op.eye_left_bone, op.eye_right_bone = st.eye_left_bone, st.eye_right_bone


def _draw_result(layout, ob):
    try:
        rep = retarget.last_report(ob)
    except ShapeSpaceError as exc:          # damaged stored data: say so, never fail the draw
        layout.label(text=str(exc), icon="ERROR")
        return
    if rep is not None:
        box = layout.box()
        col = box.column(align=True)
        span = f" ({rep.frame_range[0]:g}–{rep.frame_range[1]:g})" if rep.frame_range else ""
        col.label(text=f"{rep.action}: {rep.method}, {rep.frames} frames{span}", icon="ACTION")
        if rep.position_error_mm is not None and rep.velocity_error_mm is not None:
            col.label(text=f"error per vertex: position {rep.position_error_mm:.3g} mm, velocity "
                           f"{rep.velocity_error_mm:.3g} mm (30 cm head)")
        elif rep.velocity_error_rms is not None and rep.position_error_rms is not None:   # a 0.1 result
            col.label(text=f"error: position {rep.position_error_rms:.3g}, velocity "
                           f"{rep.velocity_error_rms:.3g} (whole mesh, of the head size)")
        if rep.clipping_frames:
            col.label(text=f"{rep.clipping_frames} frames beyond the slider ranges", icon="ERROR")
            if rep.clipped_frames:
                col.label(text=f"at {format_ranges(rep.clipped_frames, 4)}")
        if rep.keys_kept_frac is not None:
            col.label(text=f"{100 * rep.keys_kept_frac:.1f} % of the keys kept")
        box.operator("shapespace.discard_retarget", icon="LOOP_BACK").result = "SHAPE_KEYS"


def _draw_mapping(layout, ob):
    box = layout.box()
    box.label(text="Channel Mapping (overrides; the rest by name)")
    try:
        mapping = retarget.stored_mapping(ob)
    except ShapeSpaceError as exc:
        box.label(text=str(exc), icon="ERROR")
        mapping = {}
    for src, entry in sorted(mapping.items()):
        row = box.row(align=True)
        row.label(text=f"{src} → {entry.get('target')}  ×{entry.get('gain', 1.0):g} "
                       f"{entry.get('offset', 0.0):+g}")
        op = row.operator("shapespace.remove_mapping", text="", icon="X")
        op.source = src
    box.operator("shapespace.set_mapping", icon="LINKED")


def _draw_landmarks(layout, ob, st):
    box = layout.box()
    landmarks = [g.name for g in ob.vertex_groups if g.name.startswith(retarget.LANDMARK_PREFIX)]
    box.label(text=f"Landmarks: {len(landmarks)} (for meshes of another topology)", icon="VERTEXSEL")
    row = box.row(align=True)
    row.operator("shapespace.add_landmark", icon="PIVOT_CURSOR")
    sub = row.row(align=True)
    sub.enabled = st.source_kind == "MESH" and st.source_object is not None
    op = sub.operator("shapespace.landmarks_from_shapes", icon="SHAPEKEY_DATA")
    op.source_object = st.source_object.name if st.source_object else ""
