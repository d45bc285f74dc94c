import bpy

from ..bridge import posespace
from ..bridge.posespace import finalshape
from .base import ShapeSpaceSidebar


def _problem(ob) -> str:
    """What stops the mesh's correctives from working, one line ('' when nothing); a draw never raises."""
    try:
        return posespace.problem(ob)
    except Exception as exc:    # damaged data of a kind no check foresaw: say so instead of failing the draw
        return f"cannot read the pose-space data: {type(exc).__name__}"


class SHAPESPACE_UL_examples(bpy.types.UIList):
    """Pose-space examples of the active mesh"""

    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index):
        row = layout.row(align=True)
        row.prop(item, "mute", text="", icon="HIDE_ON" if item.mute else "HIDE_OFF", emboss=False)
        row.label(text=item.name, icon="SHAPEKEY_DATA")
        if item.post_deform:
            row.label(text="", icon="MOD_NORMALEDIT")     # applied after the armature
        if item.flags:
            row.label(text=item.flags, icon="ERROR")


class SHAPESPACE_UL_readers(bpy.types.UIList):
    """Controls that make up the pose space"""

    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index):
        row = layout.row(align=True)
        row.prop(item, "kind", text="")
        row.prop(item, "source", text="")
        row.prop(item, "scale", text="")


def _draw_final_shapes(layout, ob) -> None:
    """Stale examples by name (an input of their corrective changed) with Re-invert; 0.1.0 ones with Capture."""
    found = finalshape.stale_examples_cached(ob)
    if not found:
        return
    box = layout.box()
    stale = False
    for name, code, message in found:
        row = box.row(align=True)
        row.label(text=message, icon="ERROR" if code != "no_final_shape" else "INFO")
        if code == "stale_example":
            row.operator("shapespace.reinvert_example", text="", icon="FILE_REFRESH").example = name
            stale = True
        elif code == "no_final_shape":
            row.operator("shapespace.capture_final_shape", text="", icon="REC").example = name
    if stale:
        box.operator("shapespace.reinvert_all", icon="FILE_REFRESH")


class SHAPESPACE_PT_correctives(ShapeSpaceSidebar, bpy.types.Panel):
    """Pose-space correctives: sculpt at a pose, interpolate in pose space"""

    bl_label = "Pose-Space Correctives"
    bl_idname = "SHAPESPACE_PT_correctives"

    @classmethod
    def poll(cls, context):
        ob = context.active_object
        return ob is not None and ob.type == "MESH" and any(m.type == "ARMATURE" for m in ob.modifiers)

    def draw(self, context):
        layout = self.layout
        ob = context.active_object
        st = ob.shapespace_psd
        layout.prop(st, "method")
        if st.method == "WPSD":
            layout.prop(st, "wpsd_distance")
            if posespace.wpsd_distance(st) != st.wpsd_distance:     # appended or linked from before 0.2.0
                layout.label(text="Uses Skin Weighted: this pose space was made before ShapeSpace 0.2.0",
                             icon="INFO")
        layout.prop(st, "live_preview")
        message = _problem(ob)
        if message:
            layout.label(text=message, icon="ERROR")
        layout.label(text="Pose space")
        layout.template_list("SHAPESPACE_UL_readers", "", st, "readers", st, "active_reader", rows=2)
        layout.label(text="Examples")
        layout.template_list("SHAPESPACE_UL_examples", "", st, "examples", st, "active_example", rows=3)
        row = layout.row(align=True)
        row.operator("shapespace.psd_add_example", icon="ADD")
        row.operator("shapespace.psd_apply_example", icon="CHECKMARK")
        row.operator("shapespace.apply_post_deform", icon="MOD_NORMALEDIT", text="")
        row.operator("shapespace.psd_remove_example", icon="REMOVE", text="")
        row = layout.row(align=True)
        row.operator("shapespace.psd_move_example", icon="EMPTY_ARROWS")
        row.operator("shapespace.psd_mirror_example", icon="MOD_MIRROR")
        layout.operator("shapespace.push_sculpt_masked", icon="MOD_MASK")
        if st.method == "WPSD" and any(ex.post_deform for ex in st.examples):
            layout.label(text="Post-deformation examples need PSD or Shape by Example (they stay off)",
                         icon="ERROR")
        _draw_final_shapes(layout, ob)
        box = layout.box()
        box.label(text=f"Driven targets: {len(st.targets)}", icon="DRIVER")
        for t in st.targets:
            index = f"[{t.index}]" if t.index >= 0 else ""
            box.label(text=f"{t.owner.name if t.owner else '?'}: {t.data_path}{index}")
        row = box.row(align=True)
        row.operator("shapespace.psd_add_target", icon="ADD")
        row.operator("shapespace.psd_record_targets", icon="REC")
        row = layout.row(align=True)
        row.operator("shapespace.psd_update", icon="FILE_REFRESH")
        row.operator("shapespace.psd_bake", icon="REC")
        row.operator("shapespace.psd_bake_cache", icon="FILE_CACHE")
        row = layout.row(align=True)
        row.operator("shapespace.psd_confidence", icon="INFO")
        face = context.active_object.shapespace_face
        if face.confidence >= 0:   # live while Live Preview is on, else from the last run of the operator
            row.label(text=f"variance {face.confidence:.3f}")
