import bpy

from ...bridge import symmetry
from ..polls import active_mesh
from ..progress import window_progress
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_build_mirror_map(bpy.types.Operator):
    """Pair every vertex with its mirror vertex (by position, or by topology from a centre-line edge for a posed
or asymmetrically sculpted mesh) and store the table on the mesh for the symmetry tools"""

    bl_idname = "shapespace.build_mirror_map"
    bl_label = "Build Mirror Map"
    bl_options = {"REGISTER", "UNDO"}

    method: bpy.props.EnumProperty(
        name="Method",
        items=(("AUTO", "Auto", "By position; where that leaves vertices unmapped, by topology from centre-line "
                                "edges found on the mirror plane"),
               ("POSITION", "Position", "Each vertex's mirror is the vertex at its reflection (within the tolerance)"),
               ("TOPOLOGY", "Topology", "Walk the faces from a centre-line edge (select one edge in Edit Mode, "
                                        "leave Edit Mode, run): works on posed and asymmetric meshes")),
        default="AUTO")
    axis: bpy.props.EnumProperty(name="Axis", items=(("X", "X", ""), ("Y", "Y", ""), ("Z", "Z", "")), default="X")
    centre: bpy.props.EnumProperty(
        name="Plane",
        items=(("ORIGIN", "Object Origin", "The mirror plane passes through the object's origin"),
               ("BOUNDS", "Bounding-Box Centre", "The mirror plane passes through the middle of the mesh")),
        default="ORIGIN")
    tolerance: bpy.props.FloatProperty(name="Tolerance", default=1e-3, min=0.0, max=0.1, precision=5,
                                       description="Largest distance from the exact mirror position, as a "
                                                   "fraction of the mesh's bounding-box diagonal")
    edge: bpy.props.IntProperty(name="Centre Edge", default=-1, min=-1,
                                description="Topology: index of a centre-line edge (-1: the one selected edge)")

    @classmethod
    def poll(cls, context):
        return active_mesh(cls, context) is not None

    def execute(self, context):
        ob = context.active_object
        with window_progress(context, 2) as progress:
            mmap = attempt(self, symmetry.build_map, ob, self.method, self.axis, self.centre, self.tolerance,
                           self.edge)
            progress(0.5)
            if mmap is FAILED or attempt(self, symmetry.store_map, ob, mmap) is FAILED:
                return {"CANCELLED"}
        text = f"Mirror map of {ob.name}: {100 * mmap.coverage:.2f} % of {len(mmap.mirror)} vertices mapped " \
               f"({mmap.method})"
        if mmap.coverage < 1.0:
            self.report({"WARNING"}, f"{text}; {mmap.message}")
        else:
            self.report({"INFO"}, text)
        return {"FINISHED"}
