"""Shared poll checks: each returns the object or None after telling the user why (poll message)."""
from ..bridge.rig import stored as rig_stored
from ..core.result import ShapeSpaceError


def active_mesh(cls, context, editable: bool = True):
    """The active object when it is a mesh ShapeSpace can use; otherwise set the poll message and return None.

    Refused: no mesh; a mesh in Edit Mode (its shape keys and coordinates are stale until Edit Mode is left,
    and keys ShapeSpace wrote would be overwritten when it is); with ``editable`` (every operator that changes
    data), an object or mesh linked from a library (the change would be lost on save).
    """
    ob = context.active_object
    if ob is None or ob.type != "MESH":
        cls.poll_message_set("Select a mesh object")
        return None
    if ob.mode == "EDIT":
        cls.poll_message_set(f"'{ob.name}' is in Edit Mode: leave Edit Mode first (its mesh data is not "
                             "up to date until then)")
        return None
    if editable and not editable_data(ob):
        cls.poll_message_set(f"'{ob.name}' is linked from a library: make it local or a library override "
                             "first (changes to linked data are lost on save)")
        return None
    return ob


def editable_data(ob) -> bool:
    """True when ``ob``, its mesh and its shape keys can be changed and saved (not linked, not a
    non-editable library override)."""
    blocks = [ob, ob.data, getattr(ob.data, "shape_keys", None)]
    return all(b is None or (b.library is None and getattr(b, "is_editable", True)) for b in blocks)


def active_rig(cls, context, editable: bool = True):
    """The active mesh when it has shape-key targets; otherwise say why and return None."""
    ob = active_mesh(cls, context, editable)
    if ob is None:
        return None
    if ob.data.shape_keys is None or len(ob.data.shape_keys.key_blocks) < 2:
        cls.poll_message_set("The mesh has no shape keys")
        return None
    return ob


def pinned_rig(cls, context):
    """A pinnable rig that already has pins; otherwise say why and return None."""
    ob = pinnable_rig(cls, context)
    if ob is not None and not len(ob.shapespace.pins):
        cls.poll_message_set("Add a pin first")
        return None
    return ob


def pinnable_rig(cls, context):
    """A rig in a direct-manipulation mode with pins; otherwise say why and return None."""
    ob = active_rig(cls, context)
    if ob is None:
        return None
    if ob.shapespace.mode == "SLIDERS":
        cls.poll_message_set("Switch the ShapeSpace mode to Direct or Learned")
        return None
    return ob


def mesh_with_pins(cls, context):
    """The active mesh when it has pins; otherwise say why and return None."""
    ob = active_mesh(cls, context)
    if ob is None:
        return None
    if not len(ob.shapespace.pins):
        cls.poll_message_set("The mesh has no pins")
        return None
    return ob


def sculpted_key(cls, context, what: str):
    """The active rig when its active shape key is a target (not the basis); otherwise say why."""
    ob = active_rig(cls, context)
    if ob is None:
        return None
    if ob.active_shape_key_index == 0:
        cls.poll_message_set(f"Make the sculpted {what} shape the active shape key")
        return None
    return ob


def psd_mesh(cls, context, need_example: bool = False):
    """The active mesh for pose-space correctives (armature-deformed); optionally with an active example."""
    ob = active_mesh(cls, context)
    if ob is None:
        return None
    if not any(m.type == "ARMATURE" and m.object for m in ob.modifiers) and ob.shapespace_psd.armature is None:
        cls.poll_message_set("The mesh has no Armature modifier")
        return None
    if need_example:
        st = ob.shapespace_psd
        if not 0 <= st.active_example < len(st.examples):
            cls.poll_message_set("Add an example first")
            return None
    return ob


def psd_sculpt(cls, context, verb: str = "apply"):
    """The active pose-space mesh when its active example has a posed sculpt copy (not in Edit Mode, whose mesh
    data is stale until it is left); otherwise say why and return None."""
    ob = psd_mesh(cls, context, need_example=True)
    if ob is None:
        return None
    st = ob.shapespace_psd
    ex = st.examples[st.active_example]
    if ex.sculpt is None:
        cls.poll_message_set(f"Example '{ex.name}' has no posed copy to {verb}")
        return None
    if ex.sculpt.mode == "EDIT":
        cls.poll_message_set(f"The sculpt copy '{ex.sculpt.name}' is in Edit Mode: leave Edit Mode first (its "
                             "mesh data is not up to date until then)")
        return None
    return ob


def prior_rig(cls, context):
    """The active rig when it has a learnt face prior; otherwise say why and return None."""
    ob = active_rig(cls, context)
    if ob is None:
        return None
    if "shapespace_face_prior" not in ob.data.shape_keys:
        cls.poll_message_set("Learn a face prior from an animation first")
        return None
    return ob


def animated_object(cls, context):
    """The active object when it (or its shape keys) has an action; otherwise say why and return None."""
    ob = context.active_object
    if ob is None:
        cls.poll_message_set("Select an animated object")
        return None
    key = ob.data.shape_keys if ob.type == "MESH" else None
    for owner in (key, ob):
        ad = getattr(owner, "animation_data", None) if owner is not None else None
        if ad is not None and ad.action is not None:
            return ob
    cls.poll_message_set("The object has no animation")
    return None


def control_face(cls, context):
    """The face mesh whose control set an edit means (the active mesh, or with an armature active — Object or Pose
    Mode — the face :func:`bridge.rig.stored.face_for` finds); Edit Mode and linked data refused by name."""
    active = context.active_object
    if active is not None and active.mode == "EDIT":
        cls.poll_message_set(f"'{active.name}' is in Edit Mode: leave Edit Mode first")
        return None
    try:
        face = rig_stored.face_for(active, context.selected_objects)
    except ShapeSpaceError as exc:
        cls.poll_message_set(str(exc))
        return None
    if face.mode == "EDIT":
        cls.poll_message_set(f"'{face.name}' is in Edit Mode: leave Edit Mode first")
        return None
    if not editable_data(face):
        cls.poll_message_set(f"'{face.name}' is linked from a library: make it local first")
        return None
    return face
