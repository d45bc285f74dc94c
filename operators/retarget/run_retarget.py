import bpy

from ...bridge import retarget
from ...properties import KEY_SHAPES, RETARGET_METHODS
from ..polls import active_rig
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_retarget(bpy.types.Operator):
    """Retarget a Live Link Face CSV, an action or a mesh performance onto the active mesh's shape keys, into a new
action"""

    bl_idname = "shapespace.retarget"
    bl_label = "Retarget"
    bl_options = {"REGISTER", "UNDO"}

    filepath: bpy.props.StringProperty(name="CSV File", subtype="FILE_PATH",
                                       description="Live Link Face CSV (leave empty to use an action)")
    action: bpy.props.StringProperty(name="Action", description="Source action animating shape keys")
    source_object: bpy.props.StringProperty(
        name="Mesh Performance", description="An animated mesh to fit (same topology, or lm_* landmark groups)")
    method: bpy.props.EnumProperty(name="Method", items=RETARGET_METHODS, default="spacetime")
    key_tolerance: bpy.props.FloatProperty(name="Key Tolerance", default=0.0, min=0.0, max=0.1,
                                           description="Keep the fewest keys within this slider error (0: all)")
    key_shape: bpy.props.EnumProperty(name="Key Shape", items=KEY_SHAPES, default="BEZIER")
    key_pose_action: bpy.props.StringProperty(
        name="Key Poses", description="Learned method: the action keying this rig at the key-pose frames")

    @classmethod
    def poll(cls, context):
        return active_rig(cls, context) is not None

    def execute(self, context):
        if self.source_object:
            src = bpy.data.objects.get(self.source_object)
            if src is None or src.type != "MESH":
                self.report({"ERROR"}, f"no mesh named {self.source_object!r}")
                return {"CANCELLED"}
            if self.method in ("copy", "learned"):
                self.report({"ERROR"}, "a mesh performance needs a geometric method: perframe or spacetime")
                return {"CANCELLED"}
            rep = attempt(self, retarget.retarget_dense, context.active_object, src, self.method,
                          key_tolerance=self.key_tolerance, key_shape=self.key_shape)
        else:
            source = bpy.path.abspath(self.filepath) if self.filepath else self.action
            if not source:
                self.report({"ERROR"}, "choose a CSV file, an action or a mesh performance")
                return {"CANCELLED"}
            rep = attempt(self, retarget.retarget, context.active_object, source, self.method,
                          key_tolerance=self.key_tolerance, key_shape=self.key_shape,
                          key_pose_action=self.key_pose_action or None)
        if rep is FAILED:
            return {"CANCELLED"}
        for msg in rep.issues:
            self.report({"WARNING"}, msg)
        self.report({"INFO"}, f"{rep.action}: {rep.frames} frames, position error "
                              f"{rep.position_error_rms:.2g} of the size")
        return {"FINISHED"}
