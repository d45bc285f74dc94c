"""Poll checks shared by the Transfer Shapes operators: each returns the target or None after saying why."""
from ...bridge import authoring
from ..polls import active_mesh


def transfer_target(cls, context, need_landmarks: int = 0):
    """The active mesh (the target) when its source rig is set and usable; otherwise set the poll message.

    ``need_landmarks``: how many stored landmark pairs the operator needs.
    """
    ob = active_mesh(cls, context)
    if ob is None:
        return None
    if ob.get(authoring.PREVIEW_PROP) is not None:
        cls.poll_message_set("This is a registration preview: select the target mesh")
        return None
    src = ob.shapespace_authoring.source
    if src is None:
        cls.poll_message_set("Choose the source rig (Rig ▸ Transfer Shapes)")
        return None
    if src == ob:
        cls.poll_message_set("The source rig is the selected mesh itself: choose another source")
        return None
    if src.type != "MESH":
        cls.poll_message_set(f"The source rig '{src.name}' is not a mesh")
        return None
    if src.mode == "EDIT":
        cls.poll_message_set(f"The source rig '{src.name}' is in Edit Mode: leave Edit Mode first")
        return None
    if src.data.shape_keys is None or len(src.data.shape_keys.key_blocks) < 2:
        cls.poll_message_set(f"The source rig '{src.name}' has no shape keys")
        return None
    if need_landmarks:
        have, problem = authoring.landmark_count(ob)
        if problem:
            cls.poll_message_set(problem)
            return None
        if have < need_landmarks:
            cls.poll_message_set(f"Place at least {need_landmarks} landmark pairs first ({have} placed)")
            return None
    return ob


def listed(cls, context, items: str, empty: str):
    """The active mesh when its Transfer Shapes list ``items`` (``examples``, ``parts``) has rows; otherwise set
    the poll message (``empty`` when the list is empty) and return None."""
    ob = active_mesh(cls, context)
    if ob is None:
        return None
    if not len(getattr(ob.shapespace_authoring, items)):
        cls.poll_message_set(empty)
        return None
    return ob
