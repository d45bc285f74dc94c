"""The bridge: the only ShapeSpace code that reads or writes Blender data.

Everything here converts between Blender datablocks and the plain numpy
arrays / dataclasses of :mod:`core`, using ``foreach_get``/``foreach_set`` on
contiguous float32 buffers.  Differences between Blender versions (legacy
``Action.fcurves`` in 4.2 vs layered actions with slots in 4.4+/5.0) are
handled in :mod:`bridge.actions` and nowhere else.

Functions take datablocks or names as arguments and never cache ``bpy.types``
references between calls, so they are safe across undo.
"""
