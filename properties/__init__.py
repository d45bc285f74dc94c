"""Data ShapeSpace stores in the .blend, one module per capability.

The attribute names on ``bpy.types.Object`` (``shapespace``, ``shapespace_psd``,
``shapespace_retarget``, ``shapespace_face``) are the names saved in users' files:
they are part of the file format and never change (docs/ARCHITECTURE.md lists
every stored field).
"""
import bpy
from bpy.app.handlers import persistent

from ..bridge import storage
from ..bridge.live import session as live_session
from ..bridge.posespace import stored as posespace_stored
from .authoring import SHAPESPACE_PG_authoring, SHAPESPACE_PG_transfer_example, SHAPESPACE_PG_transfer_part
from .facespace import SHAPESPACE_PG_face, SHAPESPACE_PG_flagged_frame
from .live import SHAPESPACE_PG_live
from .manipulation import SHAPESPACE_PG_pin, SHAPESPACE_PG_settings
from .posespace import SHAPESPACE_PG_example, SHAPESPACE_PG_psd, SHAPESPACE_PG_reader, SHAPESPACE_PG_target
from .retarget import KEY_SHAPES, RETARGET_METHODS, SHAPESPACE_PG_retarget

__all__ = ["KEY_SHAPES", "RETARGET_METHODS", "classes", "register", "unregister"]

classes = (SHAPESPACE_PG_pin, SHAPESPACE_PG_settings, SHAPESPACE_PG_reader, SHAPESPACE_PG_target,
           SHAPESPACE_PG_example, SHAPESPACE_PG_psd, SHAPESPACE_PG_retarget,
           SHAPESPACE_PG_flagged_frame, SHAPESPACE_PG_face, SHAPESPACE_PG_live,
           SHAPESPACE_PG_transfer_example, SHAPESPACE_PG_transfer_part, SHAPESPACE_PG_authoring)


@persistent
def _upgrade_before_save(_filepath, *_):
    """Files saved by this version hold only current-version blobs (older ones are migrated on save) and every
    setting whose default changed stored explicitly."""
    posespace_stored.pin_settings(bpy.data)
    storage.upgrade_file(bpy.data)


@persistent
def _pin_after_load(_filepath, *_):
    """A file made before a default changed keeps the value it meant (e.g. its pose spaces' distance)."""
    posespace_stored.pin_settings(bpy.data)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.app.handlers.save_pre.append(_upgrade_before_save)
    bpy.app.handlers.load_post.append(_pin_after_load)
    bpy.types.Object.shapespace = bpy.props.PointerProperty(type=SHAPESPACE_PG_settings)
    bpy.types.Object.shapespace_psd = bpy.props.PointerProperty(type=SHAPESPACE_PG_psd)
    bpy.types.Object.shapespace_retarget = bpy.props.PointerProperty(type=SHAPESPACE_PG_retarget)
    bpy.types.Object.shapespace_face = bpy.props.PointerProperty(type=SHAPESPACE_PG_face)
    bpy.types.Scene.shapespace_live = bpy.props.PointerProperty(type=SHAPESPACE_PG_live)
    bpy.types.Object.shapespace_authoring = bpy.props.PointerProperty(type=SHAPESPACE_PG_authoring)
    # UI state, not data: the page of Rig ▸ Controls' channel list
    bpy.types.WindowManager.shapespace_controls_page = bpy.props.IntProperty(
        name="Page", description="The page of the control set's channels shown", min=0)
    live_session.register()


def unregister():
    live_session.unregister()    # receivers stopped: takes finished, sockets closed, threads joined, timer off
    if _upgrade_before_save in bpy.app.handlers.save_pre:
        bpy.app.handlers.save_pre.remove(_upgrade_before_save)
    if _pin_after_load in bpy.app.handlers.load_post:
        bpy.app.handlers.load_post.remove(_pin_after_load)
    del bpy.types.WindowManager.shapespace_controls_page
    del bpy.types.Object.shapespace_authoring
    del bpy.types.Scene.shapespace_live
    del bpy.types.Object.shapespace_face
    del bpy.types.Object.shapespace_retarget
    del bpy.types.Object.shapespace_psd
    del bpy.types.Object.shapespace
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
