import bpy

from ..polls import psd_mesh


class SHAPESPACE_OT_psd_remove_example(bpy.types.Operator):
    """Delete the active example, its corrective shape key and its posed copy"""

    bl_idname = "shapespace.psd_remove_example"
    bl_label = "Remove Example"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return psd_mesh(cls, context, need_example=True) is not None

    def execute(self, context):
        ob = context.active_object
        st = ob.shapespace_psd
        ex = st.examples[st.active_example]
        name = ex.name
        if ex.sculpt is not None:
            bpy.data.objects.remove(ex.sculpt)
        key = ob.data.shape_keys
        if key is not None and name in key.key_blocks:
            ob.shape_key_remove(key.key_blocks[name])
        st.examples.remove(st.active_example)
        st.active_example = max(0, min(st.active_example, len(st.examples) - 1))
        st.revision += 1
        self.report({"INFO"}, f"Removed example {name}")
        return {"FINISHED"}
