import bpy

from ...bridge import retarget
from ..polls import active_rig
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_landmarks_from_shapes(bpy.types.Operator):
    """Place landmark pairs on the active mesh and a source mesh from the shape keys they share: each pair
is the vertex that shape moves most on either mesh (chin, lids, mouth corners, …)"""

    bl_idname = "shapespace.landmarks_from_shapes"
    bl_label = "Landmarks from Shapes"
    bl_options = {"REGISTER", "UNDO"}

    source_object: bpy.props.StringProperty(name="Source Mesh", description="The other mesh, with shape keys")

    @classmethod
    def poll(cls, context):
        return active_rig(cls, context) is not None

    def execute(self, context):
        src = bpy.data.objects.get(self.source_object)
        if src is None or src.type != "MESH" or src == context.active_object:
            self.report({"ERROR"}, f"choose another mesh as the source (got {self.source_object!r})")
            return {"CANCELLED"}
        names = attempt(self, retarget.landmarks_from_shapes, src, context.active_object)
        if names is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"{len(names)} landmark pairs from shared shapes")
        return {"FINISHED"}
