import bpy

from ...bridge import authoring
from ..reporting import FAILED, attempt
from ._polls import transfer_target

METHODS = [("auto", "Automatic", "From the shapes both meshes share when the target has shapes, else from the "
            "heads' geometric features"),
           ("shapes", "From Shared Shapes", "Each shape both rigs share gives the vertex it moves most"),
           ("geometry", "From Geometry", "Nose tip, chin, eye and mouth corners, … found on both heads"),
           ("named", "Named Landmarks", "The named landmarks (eye and mouth corners, lids, lips, nose tip, chin …) "
            "found on the source from its shapes and re-found on the target's eye and mouth openings; the ones "
            "it is unsure of are named in the message and not used")]


class SHAPESPACE_OT_propose_landmarks(bpy.types.Operator):
    """Propose landmark pairs between the source rig and the active mesh (replacing the ones placed);
correct any of them with Add/Remove Landmark Pair"""

    bl_idname = "shapespace.propose_landmarks"
    bl_label = "Propose Landmarks"
    bl_options = {"REGISTER", "UNDO"}

    method: bpy.props.EnumProperty(name="Method", items=METHODS, default="auto")

    @classmethod
    def poll(cls, context):
        return transfer_target(cls, context) is not None

    def execute(self, context):
        ob = context.active_object
        result = attempt(self, authoring.propose_landmarks, ob.shapespace_authoring.source, ob, self.method)
        if result is FAILED:
            return {"CANCELLED"}
        if result.message and result.status != 0:
            self.report({"WARNING"}, result.message)
        self.report({"INFO"}, f"{result.value} landmark pairs proposed: check them with Preview Registration")
        return {"FINISHED"}
