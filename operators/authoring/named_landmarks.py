"""Operators: guided placement of the named landmarks on the active mesh (Rig ▸ Transfer Shapes ▸ Named
Landmarks): place the next name at the selected vertex, mirror the placed ones, clear, and use them as the
transfer's landmark pairs."""
import bpy

from ...bridge import authoring
from ...bridge import named_landmarks as named
from ...core.authoring.named import NAMES
from ..polls import active_mesh
from ..reporting import FAILED, attempt
from ._polls import transfer_target


def _placeable(cls, context):
    ob = active_mesh(cls, context)
    if ob is None:
        return None
    marks, problem = named.named_status(ob)
    if problem:
        cls.poll_message_set(problem)
        return None
    return ob


class SHAPESPACE_OT_place_named_landmark(bpy.types.Operator):
    """Place the next named landmark (or the one named) at the selected vertex of the active mesh
(select one vertex in Edit Mode, then return to Object Mode)"""

    bl_idname = "shapespace.place_named_landmark"
    bl_label = "Place Named Landmark"
    bl_options = {"REGISTER", "UNDO"}

    name: bpy.props.StringProperty(name="Name", default="",
                                   description="Landmark name (e.g. eye_inner_L); empty: the next one not placed")
    vertex: bpy.props.IntProperty(name="Vertex", default=-1, min=-1,
                                  description="Vertex index; −1 uses the selected vertex")

    @classmethod
    def poll(cls, context):
        return _placeable(cls, context) is not None

    def execute(self, context):
        ob = context.active_object
        name = self.name or attempt(self, named.next_name, ob)
        if name is FAILED:
            return {"CANCELLED"}
        if name is None:
            self.report({"ERROR"}, f"all {len(NAMES)} named landmarks of {ob.name!r} are placed: give a name "
                                   f"to move one")
            return {"CANCELLED"}
        v = self.vertex if self.vertex >= 0 else attempt(self, authoring.selected_vertex, ob)
        if v is FAILED:
            return {"CANCELLED"}
        if v is None:
            self.report({"ERROR"}, f"select exactly one vertex of {ob.name!r} for {name} (or give its index)")
            return {"CANCELLED"}
        marks = attempt(self, named.place, ob, name, v)
        if marks is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"{name} at vertex {v} ({len(marks)} of {len(NAMES)} placed)")
        return {"FINISHED"}


class SHAPESPACE_OT_mirror_named_landmarks(bpy.types.Operator):
    """Place the mirror partner of every placed named landmark whose partner is missing, from the mesh's
symmetry map (the stored mirror map, else one across local X = 0)"""

    bl_idname = "shapespace.mirror_named_landmarks"
    bl_label = "Mirror Named Landmarks"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        ob = _placeable(cls, context)
        if ob is not None and not named.named_landmarks(ob):
            cls.poll_message_set(f"'{ob.name}' has no named landmarks to mirror")
            return False
        return ob is not None

    def execute(self, context):
        ob = context.active_object
        filled = attempt(self, named.mirror_complete, ob)
        if filled is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"mirrored {len(filled)}: {', '.join(filled)}" if filled else "nothing to mirror")
        return {"FINISHED"}


class SHAPESPACE_OT_clear_named_landmarks(bpy.types.Operator):
    """Remove the named landmarks of the active mesh"""

    bl_idname = "shapespace.clear_named_landmarks"
    bl_label = "Clear Named Landmarks"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        ob = active_mesh(cls, context)
        if ob is not None and named.PROP not in ob.data:
            cls.poll_message_set(f"'{ob.name}' has no named landmarks")
            return False
        return ob is not None

    def execute(self, context):
        named.clear_named(context.active_object)
        return {"FINISHED"}


class SHAPESPACE_OT_use_named_landmarks(bpy.types.Operator):
    """Set the transfer's landmark pairs from the named landmarks placed on both the source rig and this mesh"""

    bl_idname = "shapespace.use_named_landmarks"
    bl_label = "Use Named Landmarks"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return transfer_target(cls, context) is not None

    def execute(self, context):
        ob = context.active_object
        count = attempt(self, authoring.use_named_landmarks, ob, ob.shapespace_authoring.source)
        if count is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"{count} landmark pairs from the named landmarks")
        return {"FINISHED"}
