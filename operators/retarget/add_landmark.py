import bpy

from ...bridge import retarget
from ..polls import active_mesh


class SHAPESPACE_OT_add_landmark(bpy.types.Operator):
    """Mark a vertex as a retargeting landmark (vertex group lm_<name>); give the corresponding vertex of
the other mesh the same name"""

    bl_idname = "shapespace.add_landmark"
    bl_label = "Add Landmark"
    bl_options = {"REGISTER", "UNDO"}

    name: bpy.props.StringProperty(name="Name", default="landmark", description="Same name on both meshes")
    vertex: bpy.props.IntProperty(name="Vertex", default=-1, min=-1,
                                  description="Vertex index; −1 uses the active vertex of the selection")

    @classmethod
    def poll(cls, context):
        return active_mesh(cls, context) is not None

    def execute(self, context):
        ob = context.active_object
        index = self.vertex
        if index < 0:
            index = retarget.selected_vertex(ob)
            if index is None:
                self.report({"ERROR"}, "select exactly one vertex (or give its index)")
                return {"CANCELLED"}
        if index >= len(ob.data.vertices):
            self.report({"ERROR"}, f"{ob.name!r} has no vertex {index}")
            return {"CANCELLED"}
        group = retarget.add_landmark(ob, self.name, index)
        self.report({"INFO"}, f"{group} = vertex {index}")
        return {"FINISHED"}
