import bpy

from .base import ShapeSpaceSidebar


class SHAPESPACE_PT_retarget(ShapeSpaceSidebar, bpy.types.Panel):
    """Retarget captures and actions onto this rig"""

    bl_label = "Retarget"
    bl_idname = "SHAPESPACE_PT_retarget"
    bl_options = {"DEFAULT_CLOSED"}

    @classmethod
    def poll(cls, context):
        ob = context.active_object
        return ob is not None and ob.type == "MESH" and ob.data.shape_keys is not None

    def draw(self, context):
        layout = self.layout
        layout.label(text="Source: a Live Link Face CSV or an action")
        op = layout.operator("shapespace.retarget", icon="ACTION")
        op.method = "spacetime"
        row = layout.row(align=True)
        row.operator("shapespace.set_mapping", icon="LINKED")
        row.operator("shapespace.add_landmark", icon="PIVOT_CURSOR")
        landmarks = [g.name for g in context.active_object.vertex_groups if g.name.startswith("lm_")]
        layout.label(text=f"{len(landmarks)} landmarks", icon="VERTEXSEL")
