"""Transfer Shapes: read (main thread) → register and transfer (a worker thread when invoked from the UI) →
write (main thread).

From the UI (``invoke``) the computation runs in a :class:`core.jobs.BackgroundJob` while a modal timer shows
window-manager progress and a status-bar line; Esc cancels it and nothing is written (the same
:class:`~operators.progress.JobModal` as Retarget).  Scripts, redo and ``EXEC_DEFAULT`` (``execute``) run the
same three steps synchronously, with window-manager progress.
"""
import bpy

from ...bridge import authoring, part_objects
from ..progress import ThreeStepJob
from ..reporting import FAILED, attempt
from ._polls import transfer_target


class SHAPESPACE_OT_transfer_shapes(ThreeStepJob, bpy.types.Operator):
    """Give the active mesh the source rig's shape keys by model transfer (registration on the landmark
pairs, then deformation transfer): in-betweens, combinations, slider ranges and masks included (Esc cancels;
nothing is written then)"""

    bl_idname = "shapespace.transfer_shapes"
    bl_label = "Transfer Shapes"
    bl_options = {"REGISTER", "UNDO"}
    job_title = "Transfer"
    compute_step = staticmethod(authoring.compute_transfer)
    write_step = staticmethod(authoring.write_transfer)
    start_step = staticmethod(authoring.start_transfer_job)
    finish_step = staticmethod(authoring.finish_transfer_job)

    @classmethod
    def poll(cls, context):
        return transfer_target(cls, context, need_landmarks=authoring.MIN_LANDMARKS) is not None

    def read_plan(self, context):
        ob = context.active_object
        st = ob.shapespace_authoring
        specs = attempt(self, authoring.stored_examples, ob)
        if specs is FAILED:
            return FAILED
        return attempt(self, authoring.read_transfer, st.source, ob, naming=st.naming, existing=st.existing,
                       unmatched_parts=st.unmatched_parts, parts=part_objects.meshes_of(st.parts_collection, ob),
                       examples=specs)

    @staticmethod
    def job_label(plan):
        return f"Transferring {len(plan.write)} shapes of {plan.source} onto {plan.target}"

    def done(self, rep):
        """Report a written transfer (or a failure) and give the operator's return value."""
        if rep is FAILED:
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
        if rep.examples:
            extra.append(f"refined to {len(rep.examples)} examples, {len(rep.examples_changed)} keys changed")
        if rep.part_objects:
            extra.append(f"also on {', '.join(p['object'] for p in rep.part_objects)}")
        failed = [k["name"] for k in rep.keys if k["failed"]]
        if failed:
            extra.append(f"{len(failed)} failed a check: {', '.join(failed[:4])}")
        tail = f" ({'; '.join(extra)})" if extra else ""
        self.report({"INFO"}, f"{len(rep.created)} shape keys transferred onto {rep.target} in {rep.seconds:.1f} s, "
                              f"registration residual {rep.registration_residual_mm:.2f} mm{tail}")
        return {"FINISHED"}
