"""The Pin tool's poll: a shape-key face (the linear path) or a face driven by its stored control set."""
from ...bridge.rig import tool
from ..polls import active_mesh, pinnable_rig


def pin_face(cls, context):
    """The active mesh when the Pin tool can drag it; otherwise say why (poll message) and return None.

    A face with a stored control set beyond its own sliders (:func:`bridge.rig.tool.uses_rig`) is dragged through
    its rig: refused by name when the set does not read, its channels are gone, a rig object is linked or in Edit
    Mode, or the mode is Sliders (:func:`bridge.rig.tool.rig_pin_problem`).  Any other face needs shape keys.
    """
    ob = active_mesh(cls, context)
    if ob is None:
        return None
    if not tool.uses_rig(ob):
        keys = ob.data.shape_keys
        if keys is None or len(keys.key_blocks) < 2:
            cls.poll_message_set(f"'{ob.name}' has no shape keys and no control set: propose its rig's controls "
                                 "(Rig ▸ Controls) to drag a bone- or driver-driven face")
            return None
        return pinnable_rig(cls, context)
    problem = tool.rig_pin_problem(ob)
    if problem:
        cls.poll_message_set(problem)
        return None
    return ob
