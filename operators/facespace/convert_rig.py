import bpy

from ...bridge import facespace
from ..polls import active_mesh
from ..progress import window_progress
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_convert_rig(bpy.types.Operator):
    """Make a converted copy of the rig: whole-face form, back to delta form, or PCA sliders (the original
is left untouched)"""

    bl_idname = "shapespace.convert_rig"
    bl_label = "Convert Rig"
    bl_options = {"REGISTER", "UNDO"}

    form: bpy.props.EnumProperty(
        name="Form",
        items=[("WHOLE_FACE", "Whole-Face", "Every key a whole face, weights summing to one with a Neutral key"),
               ("DELTA", "Delta", "Back from a whole-face copy to an ordinary relative rig"),
               ("PCA", "PCA", "Sliders that are principal components (of the rig or of its animation)")],
        default="WHOLE_FACE")
    convex: bpy.props.BoolProperty(
        name="Convex", default=True,
        description="Whole-face: drive the Neutral weight with 1 − Σ sliders so the copy matches the original")
    from_animation: bpy.props.BoolProperty(
        name="From Animation", default=False,
        description="PCA: components of the rig's animation (and convert it) instead of the whole target span")
    tolerance: bpy.props.FloatProperty(
        name="Tolerance", default=0.001, min=1e-7, max=0.5,
        description="PCA of an animation: max vertex error, as a fraction of the head size")

    @classmethod
    def poll(cls, context):
        ob = active_mesh(cls, context, editable=False)
        if ob is not None and (ob.data.shape_keys is None or len(ob.data.shape_keys.key_blocks) < 2):
            cls.poll_message_set("The mesh has no shape keys")
            return False
        return ob is not None

    def execute(self, context):
        with window_progress(context) as progress:
            new = attempt(self, facespace.convert_rig, context.active_object, self.form, self.convex,
                          self.from_animation, self.tolerance, progress=progress)
        if new is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"{new.name}: {len(new.data.shape_keys.key_blocks) - 1} keys")
        return {"FINISHED"}
