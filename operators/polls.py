"""Shared poll checks: each returns the object or None after telling the user why (poll message)."""


def active_mesh(cls, context):
    """The active object when it is a mesh; otherwise set the poll message and return None."""
    ob = context.active_object
    if ob is None or ob.type != "MESH":
        cls.poll_message_set("Select a mesh object")
        return None
    return ob
