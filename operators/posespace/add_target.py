import bpy

from ...bridge import posespace
from ...core.result import ShapeSpaceError
from ..polls import psd_mesh


class SHAPESPACE_OT_psd_add_target(bpy.types.Operator):
    """Drive a value from pose space (thesis 7.3.3): a bone channel or custom property of the armature,
or a property of the mesh; record its value at each example with Record Targets"""

    bl_idname = "shapespace.psd_add_target"
    bl_label = "Add Driven Target"
    bl_options = {"REGISTER", "UNDO"}

    data_path: bpy.props.StringProperty(name="Data Path", description='e.g. pose.bones["Arm"].scale or ["exertion"]')
    index: bpy.props.IntProperty(name="Index", default=-1, min=-1, description="Array index, −1 for a scalar")
    on_armature: bpy.props.BoolProperty(name="On Armature", default=True,
                                        description="The path is on the armature object (else on the mesh)")

    @classmethod
    def poll(cls, context):
        return psd_mesh(cls, context) is not None

    def execute(self, context):
        ob = context.active_object
        st = ob.shapespace_psd
        owner = posespace.armature_of(ob) if self.on_armature else ob
        if owner is None:
            self.report({"ERROR"}, "the mesh has no armature")
            return {"CANCELLED"}
        t = st.targets.add()
        t.owner, t.data_path, t.index = owner, self.data_path, self.index
        try:
            value = posespace.read_targets(ob)[-1]
        except (ShapeSpaceError, IndexError, TypeError) as exc:
            st.targets.remove(len(st.targets) - 1)
            self.report({"ERROR"}, str(exc) if isinstance(exc, ShapeSpaceError) else
                        f"{self.data_path!r} index {self.index} is not a number on {owner.name!r}")
            return {"CANCELLED"}
        st.revision += 1
        self.report({"INFO"}, f"Driving {owner.name}.{self.data_path} (now {value:g}); record it at each example")
        return {"FINISHED"}
