import bpy

from ...bridge import authoring
from ...core.result import ShapeSpaceError
from ._polls import transfer_target
from ..progress import window_progress


class SHAPESPACE_OT_transfer_shapes(bpy.types.Operator):
    """Give the active mesh the source rig's shape keys by model transfer (registration on the landmark
pairs, then deformation transfer): in-betweens, combinations, slider ranges and masks included"""

    bl_idname = "shapespace.transfer_shapes"
    bl_label = "Transfer Shapes"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return transfer_target(cls, context, need_landmarks=authoring.MIN_LANDMARKS) is not None

    def execute(self, context):
        ob = context.active_object
        st = ob.shapespace_authoring
        try:
            with window_progress(context) as progress:
                rep = authoring.transfer_shapes(st.source, ob, naming=st.naming, existing=st.existing,
                                                unmatched_parts=st.unmatched_parts, progress=progress)
        except ShapeSpaceError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        for warning in rep.warnings:
            self.report({"WARNING"}, warning)
        extra = []
        if rep.skipped:
            extra.append(f"{len(rep.skipped)} skipped")
        if rep.overwritten:
            extra.append(f"{len(rep.overwritten)} replaced")
        if rep.empty:
            extra.append(f"empty on the source: {', '.join(rep.empty[:4])}")
        tail = f" ({'; '.join(extra)})" if extra else ""
        self.report({"INFO"}, f"{len(rep.created)} shape keys transferred onto {ob.name} in {rep.seconds:.1f} s, "
                              f"registration residual {rep.registration_residual_mm:.2f} mm{tail}")
        return {"FINISHED"}
