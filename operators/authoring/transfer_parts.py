"""Transfer Shapes ▸ Parts: find the target's facial parts (and its part objects'), and select one to see it."""
import bpy

from ...bridge import authoring, part_objects
from ..polls import active_mesh
from ..progress import ThreeStepJob
from ..reporting import FAILED, attempt
from ._polls import listed


class SHAPESPACE_OT_find_transfer_parts(ThreeStepJob, bpy.types.Operator):
    """List the separate parts of the active mesh and its Part Objects (eyes, teeth, tongue, lashes, brows,
cavity) with the kind proposed for each and why; the kinds you set are kept (Esc cancels; the list is kept then)"""

    bl_idname = "shapespace.find_transfer_parts"
    bl_label = "Find Parts"
    bl_options = {"REGISTER", "UNDO"}
    job_title = "Find Parts"
    compute_step = staticmethod(authoring.compute_find_parts)
    write_step = staticmethod(authoring.write_find_parts)
    start_step = staticmethod(authoring.start_find_parts_job)
    finish_step = staticmethod(authoring.finish_find_parts_job)

    @classmethod
    def poll(cls, context):
        return active_mesh(cls, context) is not None

    def read_plan(self, context):
        ob = context.active_object
        self._target = ob.name
        return attempt(self, authoring.read_find_parts, ob,
                       part_objects.meshes_of(ob.shapespace_authoring.parts_collection, ob))

    @staticmethod
    def job_label(plan):
        return f"Finding the parts of {plan.target}"

    def done(self, found):
        """Report the parts listed (or a failure) and give the operator's return value."""
        if found is FAILED:
            return {"CANCELLED"}
        ob = bpy.data.objects[self._target]
        unsure = sum(row.unsure for row in ob.shapespace_authoring.parts)
        tail = f"; {unsure} unsure: check them" if unsure else ""
        self.report({"INFO"}, f"{found} parts found on {ob.name!r}{tail}")
        return {"FINISHED"}


class SHAPESPACE_OT_select_transfer_part(bpy.types.Operator):
    """Select the vertices of the active part of the list on its mesh (see them in Edit Mode)"""

    bl_idname = "shapespace.select_transfer_part"
    bl_label = "Select Part"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return listed(cls, context, "parts", "No parts listed: Find Parts first") is not None

    def execute(self, context):
        ob = context.active_object
        st = ob.shapespace_authoring
        done = attempt(self, authoring.select_part, ob, st.active_part,
                       part_objects.meshes_of(st.parts_collection, ob))
        if done is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"{done[1]} vertices of {done[0]!r} selected")
        return {"FINISHED"}
