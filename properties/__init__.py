"""Data ShapeSpace stores in the .blend, one module per capability.

The attribute names on ``bpy.types.Object`` (``shapespace``, ``shapespace_psd``,
``shapespace_retarget``, ``shapespace_face``) are the names saved in users' files:
they are part of the file format and never change (docs/ARCHITECTURE.md lists
every stored field).
"""
import bpy

from .facespace import SHAPESPACE_PG_face, SHAPESPACE_PG_flagged_frame
from .manipulation import SHAPESPACE_PG_pin, SHAPESPACE_PG_settings
from .posespace import SHAPESPACE_PG_example, SHAPESPACE_PG_psd, SHAPESPACE_PG_reader, SHAPESPACE_PG_target
from .retarget import KEY_SHAPES, RETARGET_METHODS, SHAPESPACE_PG_retarget

__all__ = ["KEY_SHAPES", "RETARGET_METHODS", "classes", "register", "unregister"]

classes = (SHAPESPACE_PG_pin, SHAPESPACE_PG_settings, SHAPESPACE_PG_reader, SHAPESPACE_PG_target,
           SHAPESPACE_PG_example, SHAPESPACE_PG_psd, SHAPESPACE_PG_retarget,
           SHAPESPACE_PG_flagged_frame, SHAPESPACE_PG_face)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Object.shapespace = bpy.props.PointerProperty(type=SHAPESPACE_PG_settings)
    bpy.types.Object.shapespace_psd = bpy.props.PointerProperty(type=SHAPESPACE_PG_psd)
    bpy.types.Object.shapespace_retarget = bpy.props.PointerProperty(type=SHAPESPACE_PG_retarget)
    bpy.types.Object.shapespace_face = bpy.props.PointerProperty(type=SHAPESPACE_PG_face)


def unregister():
    del bpy.types.Object.shapespace_face
    del bpy.types.Object.shapespace_retarget
    del bpy.types.Object.shapespace_psd
    del bpy.types.Object.shapespace
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
