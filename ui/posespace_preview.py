"""Live preview of pose-space correctives while posing and scrubbing (a depsgraph / frame handler).

Caches only numbers keyed by object name and the examples' revision, never
Blender datablocks, so undo cannot leave stale references behind.
"""
import bpy
import numpy as np
from bpy.app.handlers import persistent

from ..bridge import facespace, posespace
from ..core.result import ShapeSpaceError

_cache = {}      # object name -> [revision, method, deformer, names, last pose, target driver, GP model]
_busy = []       # re-entrancy guard: writing key values triggers another depsgraph update


def refresh(obj) -> bool:
    """Update ``obj``'s correctives if its pose changed; True when it wrote new values."""
    st = obj.shapespace_psd
    entry = _cache.get(obj.name)
    if entry is None or entry[0] != st.revision or entry[1] != st.method:
        deformer, names = posespace.trained_deformer(obj)
        entry = [st.revision, st.method, deformer, names, None, posespace.target_driver(obj),
                 facespace.confidence_model(deformer)]
        _cache[obj.name] = entry
    pose = posespace.read_pose(obj)
    if entry[4] is not None and entry[4].shape == pose.shape and np.allclose(entry[4], pose, atol=1e-9):
        return False
    posespace.preview(obj, entry[2], entry[3], entry[5])
    obj.shapespace_face.confidence = float(entry[6].variance(pose))    # the panel's live confidence
    entry[4] = pose
    return True


@persistent
def _on_update(scene, depsgraph=None):
    if _busy:
        return
    _busy.append(True)
    try:
        for obj in scene.objects:
            if obj.type == "MESH" and obj.shapespace_psd.live_preview and len(obj.shapespace_psd.examples):
                try:
                    refresh(obj)
                except ShapeSpaceError:
                    continue  # the panel shows the problem; playback must not stop
    finally:
        _busy.pop()


def register():
    bpy.app.handlers.depsgraph_update_post.append(_on_update)
    bpy.app.handlers.frame_change_post.append(_on_update)


def unregister():
    for handlers in (bpy.app.handlers.depsgraph_update_post, bpy.app.handlers.frame_change_post):
        while _on_update in handlers:
            handlers.remove(_on_update)
    _cache.clear()
