"""Face Space sidebar panel: representations, diagnostics, the face prior and curve repair (thesis 3.7, ch. 6,
9.3).  Reads only: every button is an operator of :mod:`operators.facespace`."""
import bpy

from ..bridge import facespace
from ..core.result import ShapeSpaceError
from .base import ShapeKeyPanel


def _fmt(value, spec: str = ".2f") -> str:
    """A stored number for display (stored NaN and infinity read back as ``None``)."""
    return "–" if value is None else format(value, spec)


class SHAPESPACE_UL_flagged_frames(bpy.types.UIList):
    """Frames the face prior finds implausible"""

    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index):
        row = layout.row(align=True)
        row.operator("shapespace.go_to_frame", text=str(item.frame), emboss=False).frame = item.frame
        row.label(text=item.reason.replace("_", " "), icon="ERROR")


class SHAPESPACE_PT_face_space(ShapeKeyPanel, bpy.types.Panel):
    """Representations, diagnostics, the face prior and curve repair"""

    bl_label = "Face Space"
    bl_idname = "SHAPESPACE_PT_face_space"

    def draw(self, context):
        layout = self.layout
        ob = context.active_object
        face = ob.shapespace_face

        box = layout.box()
        box.label(text="Representation", icon="SHAPEKEY_DATA")
        row = box.row(align=True)
        for form, label in (("WHOLE_FACE", "Whole-Face"), ("DELTA", "Delta"), ("PCA", "PCA")):
            row.operator("shapespace.convert_rig", text=label).form = form
        box.operator("shapespace.make_convex", icon="MESH_ICOSPHERE")
        issue = facespace.whole_face_issue(ob)
        if issue:
            box.label(text=issue, icon="ERROR")
        try:
            analysis = facespace.stored_analysis(ob)
        except ShapeSpaceError as exc:       # damaged report: say so, draw the rest
            analysis = {}
            box.label(text=str(exc), icon="ERROR")
        row = box.row(align=True)
        row.operator("shapespace.compression_report", icon="FILE_ARCHIVE")
        comp = analysis.get("compression")
        if comp and comp.get("components") is not None:
            box.label(text=f"{comp['components']} of {comp['targets']} components ({_fmt(comp['ratio'])}:1) "
                           f"at {comp['tol']:.3g}")

        box = layout.box()
        box.label(text="Diagnostics", icon="VIEWZOOM")
        box.operator("shapespace.analyse_rig", icon="IMAGE_DATA")
        coh = analysis.get("coherence")
        if coh:
            img = bpy.data.images.get(coh["image"])
            if img is not None:
                box.template_icon(icon_value=img.preview_ensure().icon_id, scale=8.0)
            box.label(text=f"mutual coherence {_fmt(coh['mutual_coherence'], '.3f')}")
            for name in coh["empty_targets"]:
                box.label(text=f"{name}: empty", icon="ERROR")
            for a, b, c in coh["similar_pairs"][:6]:
                box.label(text=f"{a} ≈ {b} ({c:.2f})", icon="ERROR")
            if coh.get("sparsity"):
                bs, pc = coh["sparsity"]["blendshape"], coh["sparsity"]["pca"]
                box.label(text=f"idle samples: blendshape {_fmt(bs['curve_small_fraction'])}, "
                               f"PCA {_fmt(pc['curve_small_fraction'])}")

        box = layout.box()
        box.label(text="Face Prior", icon="FORCE_HARMONIC")
        box.operator("shapespace.learn_face_prior", icon="LIGHT")
        if facespace.has_prior(ob):
            try:
                m = facespace.meter(ob)
                col = box.column(align=True)
                col.label(text=f"face norm {m.norm:.2f} (typical ≈ {m.shell_radius:.2f})")
                col.label(text=f"percentile {100 * m.percentile:.1f} % — {m.plausibility.replace('_', ' ')}",
                          icon="CHECKMARK" if m.plausibility == "typical" else "ERROR")
            except ShapeSpaceError as exc:   # a stale or damaged prior must not break the sidebar
                box.label(text=str(exc), icon="ERROR")
            box.operator("shapespace.find_implausible_frames", icon="ZOOM_ALL")
            if len(face.implausible):
                box.template_list("SHAPESPACE_UL_flagged_frames", "", face, "implausible", face,
                                  "active_implausible", rows=3)
            row = box.row(align=True)
            row.operator("shapespace.fill_between", text="Shell In-Betweens").mode = "SHELL"
            row.operator("shapespace.fill_between", text="Linear").mode = "LINEAR"

        box = layout.box()
        box.label(text="Inpaint a Gap", icon="MOD_SMOOTH")
        box.prop(face, "gap_path", text="")
        row = box.row(align=True)
        row.prop(face, "gap_index")
        row.prop(face, "gap_start")
        row.prop(face, "gap_end")
        op = box.operator("shapespace.inpaint_gap", icon="BRUSH_DATA")
        op.data_path, op.index = face.gap_path, face.gap_index
        op.frame_start, op.frame_end = face.gap_start, face.gap_end
