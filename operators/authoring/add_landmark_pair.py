import bpy

from ...bridge import authoring
from ..reporting import FAILED, attempt
from ._polls import transfer_target


class SHAPESPACE_OT_add_landmark_pair(bpy.types.Operator):
    """Add a landmark pair: the selected vertex of the source rig and the selected vertex of the active mesh
(select one vertex on each in Edit Mode, then return to Object Mode)"""

    bl_idname = "shapespace.add_landmark_pair"
    bl_label = "Add Landmark Pair"
    bl_options = {"REGISTER", "UNDO"}

    source_vertex: bpy.props.IntProperty(name="Source Vertex", default=-1, min=-1,
                                         description="Vertex of the source rig; −1 uses its selected vertex")
    target_vertex: bpy.props.IntProperty(name="Target Vertex", default=-1, min=-1,
                                         description="Vertex of the active mesh; −1 uses its selected vertex")

    @classmethod
    def poll(cls, context):
        return transfer_target(cls, context) is not None

    def execute(self, context):
        ob = context.active_object
        src = ob.shapespace_authoring.source
        a = self.source_vertex if self.source_vertex >= 0 else authoring.selected_vertex(src)
        b = self.target_vertex if self.target_vertex >= 0 else authoring.selected_vertex(ob)
        for index, mesh in ((a, src), (b, ob)):
            if index is None:
                self.report({"ERROR"}, f"select exactly one vertex of {mesh.name!r} (or give its index)")
                return {"CANCELLED"}
        count = attempt(self, authoring.add_landmark, ob, src, a, b)
        if count is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"landmark pair {src.name}:{a} ↔ {ob.name}:{b} ({count} pairs)")
        return {"FINISHED"}
