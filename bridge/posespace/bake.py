"""Baking the correctives so a file plays back without ShapeSpace: example-key weights as shape-key
animation (PSD, Shape-by-Example) or the corrected mesh as a PC2 point cache (every method)."""
from __future__ import annotations

import os

import bpy
import numpy as np

from ...core.errors import ErrorCode
from ...core.pointcache import write_pc2
from ...core.result import ShapeSpaceError
from .. import actions, shapekeys
from .examples import pre_armature_positions
from .pose import read_pose, settings
from .stored import WPSD_KEY
from .targets import target_driver
from .training import trained_deformer

#: The Mesh Cache modifier that plays a baked point cache.
MESH_CACHE_NAME = "ShapeSpace Correctives"


def _sample_weights(obj, scene, deformer, frames):
    """Example weights (f, K) and driven-target values (f, t) at every frame (the scene frame is restored)."""
    current = scene.frame_current
    driver = target_driver(obj)
    weights = np.empty((frames.size, deformer.n_examples))
    targets = np.empty((frames.size, len(settings(obj).targets)))
    try:
        for i, f in enumerate(frames):
            scene.frame_set(int(f))
            pose = read_pose(obj)
            weights[i] = deformer.weights(pose)
            if driver is not None:
                targets[i] = list(driver(pose).values())
    finally:
        scene.frame_set(current)
    return weights, targets


def bake_weights(obj, scene, start: int, end: int) -> int:
    """Key every example key's weight on every frame of [start, end] (playback without the add-on).

    Driven targets are keyed too.  Returns the number of example keys baked.
    """
    deformer, names = trained_deformer(obj)
    if deformer.method == "wpsd":
        raise ShapeSpaceError("weighted PSD is per vertex and cannot be baked into example keys", ErrorCode.METHOD)
    frames = np.arange(start, end + 1, dtype=np.float64)
    weights, targets = _sample_weights(obj, scene, deformer, frames)
    for j, t in enumerate(settings(obj).targets):
        actions.write_curve(t.owner, t.data_path, frames, targets[:, j], index=max(t.index, 0))
    key = obj.data.shape_keys
    action = actions.active_action(key)
    if action is None:
        action = actions.new_action(key, f"{obj.name}_PSD")
    for j, name in enumerate(names):
        actions.write_curve(key, actions.shape_key_path(name), frames, weights[:, j])
    return len(names)


def cache_path(obj, filepath: str = "") -> str:
    """The absolute PC2 path for ``filepath`` (may be ``//``-relative); empty: ``<object>_correctives.pc2``
    next to the saved .blend."""
    if not filepath:
        if not bpy.data.filepath:
            raise ShapeSpaceError("save the file first or give a PC2 file path", ErrorCode.MISSING_FILE)
        filepath = os.path.join(os.path.dirname(bpy.data.filepath), f"{obj.name}_correctives.pc2")
    return bpy.path.abspath(filepath)


def _sample_meshes(obj, scene, deformer, frames) -> np.ndarray:
    """The corrected pre-armature mesh (f, p, 3) at every frame, Live Preview paused meanwhile."""
    current = scene.frame_current
    st = settings(obj)
    was_live = st.live_preview
    st.live_preview = False
    out = np.empty((len(frames), len(obj.data.vertices), 3))
    try:
        for i, f in enumerate(frames):
            scene.frame_set(f)
            out[i] = pre_armature_positions(obj) + deformer.evaluate(read_pose(obj))
    finally:
        scene.frame_set(current)
        st.live_preview = was_live
    return out


def _mesh_cache_modifier(obj, path: str, start: int):
    """The Mesh Cache modifier playing ``path`` from frame ``start``, first in the stack (before the armature)."""
    mod = obj.modifiers.get(MESH_CACHE_NAME) or obj.modifiers.new(MESH_CACHE_NAME, "MESH_CACHE")
    mod.cache_format = "PC2"
    mod.filepath = path
    mod.deform_mode = "OVERWRITE"
    mod.time_mode = "FRAME"
    mod.play_mode = "SCENE"
    mod.frame_start = float(start)
    mod.frame_scale = 1.0
    mod.interpolation = "NONE"
    index = list(obj.modifiers).index(mod)
    if index != 0:
        with bpy.context.temp_override(object=obj):
            bpy.ops.object.modifier_move_to_index(modifier=mod.name, index=0)
    return mod


def bake_point_cache(obj, scene, start: int, end: int, path: str) -> str:
    """Bake the corrected pre-armature mesh of every frame to PC2 and play it with a Mesh Cache modifier.

    Works for every method (weighted PSD included): the Mesh Cache modifier,
    placed before the Armature modifier, replaces the shape-key result with
    the corrected one, so playback needs neither ShapeSpace nor Python.
    ``path``: an absolute file path (see :func:`cache_path`).  Returns the modifier's name.
    """
    deformer, names = trained_deformer(obj)
    out = _sample_meshes(obj, scene, deformer, list(range(start, end + 1)))
    write_pc2(path, out, start_frame=float(start), sample_rate=1.0)
    mod = _mesh_cache_modifier(obj, path, start)
    # the correctives now come from the cache: keep the example keys (and the WPSD preview key) at 0
    key = obj.data.shape_keys
    zero = [n for n in list(names) + [WPSD_KEY] if n in key.key_blocks]
    shapekeys.write_slider_values(obj, zero, np.zeros(len(zero)))
    return mod.name
