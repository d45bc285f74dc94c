"""Baking the correctives so a file plays back without ShapeSpace: example-key weights as shape-key
animation (PSD, Shape-by-Example) or the corrected mesh as a PC2 point cache (every method).

Both sample every frame first and write only when every sample is sound; both bake only the active
method's correctives (the other correctives' keys — weighted PSD's key, muted examples — are set to 0).
"""
from __future__ import annotations

import os
import tempfile

import bpy
import numpy as np

from ...core.errors import ErrorCode
from ...core.paths import check_output_file
from ...core.pointcache import write_pc2
from ...core.result import ShapeSpaceError
from .. import actions, shapekeys
from .correctives import check_finite_positions, check_not_editing, example_keys, pre_armature_positions, shape_keys
from .pose import read_pose, settings
from .targets import target_driver
from .training import trained_deformer

#: The Mesh Cache modifier that plays a baked point cache.
MESH_CACHE_NAME = "ShapeSpace Correctives"
_PC2_MAGIC = b"POINTCACHE2\0"


def _tick(progress, done: int, total: int) -> None:
    if progress is not None:
        progress(done / max(total, 1))


def _sample_weights(obj, scene, deformer, frames, progress=None):
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
            _tick(progress, i + 1, frames.size)
    finally:
        scene.frame_set(current)
    if not (np.isfinite(weights).all() and np.isfinite(targets).all()):
        raise ShapeSpaceError(f"the pose-space weights of {obj.name!r} are not finite on some frame: nothing "
                              "was baked", ErrorCode.NON_FINITE)
    return weights, targets


def _other_correctives(obj, names) -> list:
    """The correctives' keys that exist but are not baked (muted examples, weighted PSD's key)."""
    blocks = shape_keys(obj).key_blocks
    return sorted(n for n in example_keys(obj) if n in blocks and n not in set(names))


def _silence(obj, names, frames) -> None:
    """Set the keys ``names`` to 0; a key already animated gets a curve at 0 over ``frames`` instead."""
    key = shape_keys(obj)
    action = actions.active_action(key)
    animated = {fc.data_path for fc in actions.fcurves(action, key)} if action is not None else set()
    for name in names:
        if actions.shape_key_path(name) in animated:
            actions.write_curve(key, actions.shape_key_path(name), frames, np.zeros(frames.size))
    shapekeys.write_slider_values(obj, names, np.zeros(len(names)))


def bake_weights(obj, scene, start: int, end: int, progress=None) -> int:
    """Key every example key's weight on every frame of [start, end] (playback without the add-on).

    Driven targets are keyed too; weighted PSD's key and muted examples' keys are set to 0 (only the
    active method's correctives play).  ``progress``: called with the fraction of frames sampled.
    Returns the number of example keys baked.
    """
    check_not_editing(obj)
    deformer, names = trained_deformer(obj)
    if deformer.method == "wpsd":
        raise ShapeSpaceError("weighted PSD is per vertex and cannot be baked into example keys", ErrorCode.METHOD)
    frames = np.arange(start, end + 1, dtype=np.float64)
    weights, targets = _sample_weights(obj, scene, deformer, frames, progress)
    for j, t in enumerate(settings(obj).targets):
        actions.write_curve(t.owner, t.data_path, frames, targets[:, j], index=max(t.index, 0))
    key = obj.data.shape_keys
    action = actions.active_action(key)
    if action is None:
        action = actions.new_action(key, f"{obj.name}_PSD")
    for j, name in enumerate(names):
        actions.write_curve(key, actions.shape_key_path(name), frames, weights[:, j])
    _silence(obj, _other_correctives(obj, names), frames)
    return len(names)


def _is_point_cache(path: str) -> bool:
    try:
        with open(path, "rb") as fh:
            return fh.read(len(_PC2_MAGIC)) == _PC2_MAGIC
    except OSError:
        return False


def _own_cache(obj, path: str) -> bool:
    """True when ``path`` is the file ``obj``'s ShapeSpace Mesh Cache modifier already plays (a re-bake)."""
    mod = obj.modifiers.get(MESH_CACHE_NAME)
    if mod is None or mod.type != "MESH_CACHE" or not mod.filepath:
        return False
    played = os.path.normpath(os.path.abspath(bpy.path.abspath(mod.filepath)))
    return os.path.normcase(played) == os.path.normcase(path)


def default_cache_name(obj) -> str:
    """``<object>_correctives.pc2`` with the object's name made safe for a file name (no folder, no '..')."""
    return f"{bpy.path.clean_name(obj.name) or 'mesh'}_correctives.pc2"


def cache_path(obj, filepath: str = "", overwrite: bool = False) -> str:
    """The absolute PC2 path to bake to.

    ``filepath`` (may be ``//``-relative) is the user's choice; empty: :func:`default_cache_name` in the
    saved .blend's folder (the object's name can never lead elsewhere).  Refused: the .blend file itself,
    a folder, a missing folder, and — unless ``overwrite`` — an existing file that is not a point cache
    (chosen path) or that this object's Mesh Cache modifier does not already play (default path).
    """
    chosen = bool(filepath)
    if not chosen:
        if not bpy.data.filepath:
            raise ShapeSpaceError("save the file first or give a PC2 file path", ErrorCode.MISSING_FILE)
        filepath = os.path.join(os.path.dirname(bpy.data.filepath), default_cache_name(obj))
    path = os.path.normpath(os.path.abspath(bpy.path.abspath(filepath)))
    if chosen:
        accept, what, hint = _is_point_cache, "a point cache", "choose another file or tick Overwrite"
    else:
        accept, what, hint = (lambda p: _own_cache(obj, p)), "this mesh's point cache", \
            "the default file name already exists: give a file path or tick Overwrite"
    return check_output_file(path, what=what, inputs=(bpy.data.filepath,), replaceable=accept, replace_hint=hint,
                             overwrite=overwrite)


def _sample_meshes(obj, scene, deformer, frames, progress=None) -> np.ndarray:
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
            check_finite_positions(out[i], f"the corrected mesh of {obj.name!r} at frame {f}")
            _tick(progress, i + 1, len(frames))
    finally:
        scene.frame_set(current)
        st.live_preview = was_live
    return out


def _write_file(path: str, positions: np.ndarray, start: int) -> None:
    """Write the PC2 next to ``path`` first and move it into place: a failed write leaves ``path`` as it was."""
    fd, tmp = tempfile.mkstemp(prefix=".shapespace-", suffix=".pc2.tmp", dir=os.path.dirname(path))
    os.close(fd)
    try:
        write_pc2(tmp, positions, start_frame=float(start), sample_rate=1.0)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def stored_cache_path(path: str, relative: bool | None = None) -> str:
    """How the Mesh Cache modifier stores the absolute ``path``: ``//``-relative to the saved .blend when
    ``relative`` (default: Blender's *Relative Paths* preference), else absolute.

    An unsaved file has no folder to be relative to, and a path on another drive (Windows) cannot be
    relative: both stay absolute.
    """
    if relative is None:
        relative = bool(bpy.context.preferences.filepaths.use_relative_paths)
    if not relative or not bpy.data.filepath:
        return path
    try:
        return bpy.path.relpath(path)
    except ValueError:          # another drive
        return path


def _mesh_cache_modifier(obj, path: str, start: int, relative: bool | None = None):
    """The Mesh Cache modifier playing ``path`` from frame ``start``, first in the stack (before the armature)."""
    mod = obj.modifiers.get(MESH_CACHE_NAME) or obj.modifiers.new(MESH_CACHE_NAME, "MESH_CACHE")
    mod.cache_format = "PC2"
    mod.filepath = stored_cache_path(path, relative)
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


def bake_point_cache(obj, scene, start: int, end: int, path: str, progress=None,
                     relative: bool | None = None) -> str:
    """Bake the corrected pre-armature mesh of every frame to PC2 and play it with a Mesh Cache modifier.

    Works for every method (weighted PSD included): the Mesh Cache modifier,
    placed before the Armature modifier, replaces the shape-key result with
    the corrected one, so playback needs neither ShapeSpace nor Python.
    ``path``: an absolute file path (see :func:`cache_path`); the modifier stores it as
    :func:`stored_cache_path` does (``//``-relative to the saved .blend by Blender's preference, so a
    moved project keeps playing).  ``progress``: called with the fraction of frames sampled.  Returns the
    modifier's name.
    """
    check_not_editing(obj)
    deformer, names = trained_deformer(obj)
    out = _sample_meshes(obj, scene, deformer, list(range(start, end + 1)), progress)
    _write_file(path, out, start)
    mod = _mesh_cache_modifier(obj, path, start, relative)
    # the correctives now come from the cache: every corrective key (and the WPSD preview key) at 0
    blocks = obj.data.shape_keys.key_blocks
    zero = sorted(n for n in example_keys(obj) if n in blocks)
    shapekeys.write_slider_values(obj, zero, np.zeros(len(zero)))
    return mod.name
