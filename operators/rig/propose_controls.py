import bpy

from ...bridge.rig import proposal, stored
from ..polls import control_face
from ..progress import window_progress
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_propose_controls(bpy.types.Operator):
    """Find the channels that move the face (bone rotation and location axes, shape-key sliders, custom properties
drivers read), probing each through Blender's evaluation, and add them to the face's control set"""

    bl_idname = "shapespace.propose_controls"
    bl_label = "Propose Controls"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return control_face(cls, context) is not None

    def execute(self, context):
        face = control_face(self, context)
        arm = stored.armature_for(face, context.active_object)
        with window_progress(context) as progress:
            found = attempt(self, proposal.propose_and_store, face, arm, progress)
        if found is FAILED:
            return {"CANCELLED"}
        report, added = found
        if not report.proposed:
            self.report({"ERROR"}, f"{face.name}: no channel deforms the face; {report.summary()}")
            return {"CANCELLED"}
        self.report({"INFO"}, f"{face.name}: {report.summary()}; {len(added)} added")
        return {"FINISHED"}
