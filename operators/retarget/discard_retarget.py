"""Discard Result: give back what one of the face's last retargets keyed.

A face can remember two results: the last retarget onto its rig controls (:mod:`bridge.rig.last_take`: every
datablock it keyed — armature, property owners, shape keys — plays its action from before and every channel gets its
value back) and the last retarget onto its shape keys (:func:`bridge.retarget.discard_last`).  The panel's button
under each result names which (``result``); a script's call with ``'AUTO'`` discards the only one there is and is
refused when there are both.  Both only ever restore: a rig that no longer plays the result is refused by name, with
nothing changed.
"""
import bpy

from ...bridge import retarget
from ...bridge.rig import last_take
from ..polls import active_rig
from ..reporting import FAILED, attempt


def _remembered(ob) -> set:
    return {kind for kind, has in (("CONTROLS", last_take.has_result(ob)), ("SHAPE_KEYS", retarget.has_result(ob)))
            if has}


class SHAPESPACE_OT_discard_retarget(bpy.types.Operator):
    """Discard a retarget result: what it keyed plays the action(s) it had before, the retargeted actions are
deleted"""

    bl_idname = "shapespace.discard_retarget"
    bl_label = "Discard Result"
    bl_options = {"REGISTER", "UNDO"}

    result: bpy.props.EnumProperty(
        name="Result", default="AUTO",
        items=[("AUTO", "Auto", "The only result the face remembers (refused when it remembers both)"),
               ("CONTROLS", "Rig Controls", "The last retarget onto the face's rig controls"),
               ("SHAPE_KEYS", "Shape Keys", "The last retarget onto the face's shape keys")])

    @classmethod
    def poll(cls, context):
        ob = active_rig(cls, context)
        if ob is not None and not _remembered(ob):
            cls.poll_message_set("Nothing retargeted onto this rig yet")
            return False
        return ob is not None

    def _which(self, ob) -> str:
        """The result to discard, or '' (reported) when there is none or the choice is ambiguous."""
        kinds = _remembered(ob)
        if self.result != "AUTO":
            if self.result in kinds:
                return self.result
            what = "its rig controls" if self.result == "CONTROLS" else "its shape keys"
            self.report({"ERROR"}, f"{ob.name!r} has no retarget onto {what} to discard")
            return ""
        if len(kinds) == 1:
            return kinds.pop()
        self.report({"ERROR"}, f"{ob.name!r} remembers a retarget onto its rig controls and one onto its shape keys: "
                               "choose which (result='CONTROLS' or 'SHAPE_KEYS')")
        return ""

    def execute(self, context):
        ob = context.active_object
        which = self._which(ob)
        if not which:
            return {"CANCELLED"}
        if which == "CONTROLS":
            restored = attempt(self, last_take.discard, ob)
            if restored is FAILED:
                return {"CANCELLED"}
            self.report({"INFO"}, "rig controls back to " + ", ".join(
                f"{name!r}" if prev else f"{name!r}: no animation" for name, prev in restored))
            return {"FINISHED"}
        restored = attempt(self, retarget.discard_last, ob)
        if restored is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"back to {restored!r}" if restored else "back to no animation")
        return {"FINISHED"}
