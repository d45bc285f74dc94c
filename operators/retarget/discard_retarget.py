"""Discard Result: give back what the face's last retarget keyed.

A face that remembers a retarget onto its rig controls (:mod:`bridge.rig.last_take`) discards that first: every
datablock it keyed (armature, property owners, shape keys) plays its action from before and every channel gets its
value back; otherwise the last retarget onto its shape keys (:func:`bridge.retarget.discard_last`).  Both only ever
restore: a rig that no longer plays the result is refused by name, with nothing changed.
"""
import bpy

from ...bridge import retarget
from ...bridge.rig import last_take
from ..polls import active_rig
from ..reporting import FAILED, attempt


class SHAPESPACE_OT_discard_retarget(bpy.types.Operator):
    """Discard the last retarget: the rig plays the action(s) it had before, the retargeted actions are deleted"""

    bl_idname = "shapespace.discard_retarget"
    bl_label = "Discard Result"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        ob = active_rig(cls, context)
        if ob is not None and not (last_take.has_result(ob) or retarget.has_result(ob)):
            cls.poll_message_set("Nothing retargeted onto this rig yet")
            return False
        return ob is not None

    def execute(self, context):
        ob = context.active_object
        if last_take.has_result(ob):
            restored = attempt(self, last_take.discard, ob)
            if restored is FAILED:
                return {"CANCELLED"}
            named = [n for n in restored if n]
            self.report({"INFO"}, f"rig controls back to {', '.join(map(repr, named))}" if named
                        else "rig controls back to no animation")
            return {"FINISHED"}
        restored = attempt(self, retarget.discard_last, ob)
        if restored is FAILED:
            return {"CANCELLED"}
        self.report({"INFO"}, f"back to {restored!r}" if restored else "back to no animation")
        return {"FINISHED"}
