import bpy

from ...bridge.rig import stored
from ..polls import control_face
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_add_control_property(bpy.types.Operator):
    """Add a custom property (["name"] or pose.bones["bone"]["name"]) or a shape-key slider
(data.shape_keys.key_blocks["key"].value) of an object to the face's control set"""

    bl_idname = "shapespace.add_control_property"
    bl_label = "Add Property"
    bl_options = {"REGISTER", "UNDO"}

    data_path: bpy.props.StringProperty(name="Data Path", description="Path from the object, e.g. "
                                        "pose.bones[\"jaw\"][\"open\"] or [\"blink\"]")
    object_name: bpy.props.StringProperty(name="Object", description="The object the path starts from "
                                          "(empty: the control set's armature, else the face)")

    @classmethod
    def poll(cls, context):
        return control_face(cls, context) is not None

    def invoke(self, context, event):
        return context.window_manager.invoke_props_dialog(self)

    def execute(self, context):
        face = control_face(self, context)
        owner = attempt(self, stored.path_owner, face, self.object_name, context.active_object)
        if owner is FAILED:
            return {"CANCELLED"}
        entry = attempt(self, stored.add_path, face, owner, self.data_path)
        if entry is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"{face.name}: added {entry.label}")
        return {"FINISHED"}
