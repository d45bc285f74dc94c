"""The temporary scene an export writes from: copies of the chosen objects with everything baked to plain data.

Nothing of the user's file is changed: objects, meshes (with their shape keys) and armatures are copied
into a new scene, the copies' shape keys are rewritten as plain relative keys (masks and keys relative to
other keys folded in), drivers are replaced by keyed weights, weights outside [0, 1] are split
(:mod:`core.export.weights`), and everything created here is removed again when the scene is closed.
"""
from __future__ import annotations

import os
import tempfile

import bpy
import numpy as np

from ...core.export.weights import NEGATIVE_SUFFIX, split_weights
from ...core.pointcache import write_pc2
from .. import actions
from ..arrays import read_float, write_float
from ..meshes import group_weight_vector

#: Name of the temporary scene (removed after the export).
SCENE_NAME = "ShapeSpace Export"
#: Name prefix of the per-frame keys that carry weighted PSD through glTF/FBX.
FRAME_KEY_PREFIX = "frame_"


class ExportScene:
    """A temporary scene of copies, removed (with every datablock it created) on :meth:`close`.

    Use as a context manager.  ``copies`` maps each source object's name to its copy.
    """

    def __init__(self, source_scene, objects, start: int, end: int):
        self.source_scene = source_scene
        self.objects = list(objects)
        self.start, self.end = int(start), int(end)
        self.copies = {}
        self.created = []           # (collection name, datablock) in creation order
        self.tmpdir = None
        self.scene = None

    # -- lifetime ---------------------------------------------------------------------------------------
    def __enter__(self):
        self.scene = bpy.data.scenes.new(SCENE_NAME)
        self.created.append(("scenes", self.scene))
        self._settings_from(self.source_scene)
        for ob in self.objects:
            self._copy(ob)
        for ob in self.objects:
            self._relink(ob, self.copies[ob.name])
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def close(self) -> None:
        """Remove every datablock this scene created (objects first, then their data, actions, the scene)."""
        order = {"objects": 0, "meshes": 1, "armatures": 1, "actions": 2, "scenes": 3}
        for kind, block in sorted(reversed(self.created), key=lambda item: order[item[0]]):
            coll = getattr(bpy.data, kind)
            try:
                if block.name in coll and coll[block.name] == block:
                    coll.remove(block)
            except ReferenceError:
                pass
        self.created.clear()
        if self.tmpdir is not None:
            for name in os.listdir(self.tmpdir):
                os.remove(os.path.join(self.tmpdir, name))
            os.rmdir(self.tmpdir)
            self.tmpdir = None

    def _settings_from(self, src) -> None:
        sc = self.scene
        sc.render.fps, sc.render.fps_base = src.render.fps, src.render.fps_base
        sc.frame_start, sc.frame_end = self.start, self.end
        sc.frame_current = self.start
        us, ud = src.unit_settings, sc.unit_settings
        ud.system, ud.scale_length, ud.length_unit = us.system, us.scale_length, us.length_unit

    def _copy(self, ob) -> None:
        c = ob.copy()
        self.created.append(("objects", c))
        if ob.data is not None:
            c.data = ob.data.copy()
            self.created.append(("meshes" if ob.type == "MESH" else "armatures", c.data))
        if hasattr(c, "shapespace_psd"):
            c.shapespace_psd.live_preview = False        # ShapeSpace's handlers leave the copy alone
        self.scene.collection.objects.link(c)
        self.copies[ob.name] = c

    def _relink(self, ob, c) -> None:
        """Point the copy at the copies (parent, Armature modifiers); world transform kept."""
        if ob.parent is not None:
            if ob.parent.name in self.copies:
                c.parent = self.copies[ob.parent.name]
            else:
                c.parent = None
                c.matrix_world = ob.matrix_world.copy()
        for mod in getattr(c, "modifiers", []):
            if mod.type == "ARMATURE" and mod.object is not None and mod.object.name in self.copies:
                mod.object = self.copies[mod.object.name]

    def temp_dir(self) -> str:
        if self.tmpdir is None:
            self.tmpdir = tempfile.mkdtemp(prefix="shapespace-export-")
        return self.tmpdir

    def override(self) -> dict:
        """Context members that make Blender's exporters see this scene."""
        return {"scene": self.scene, "view_layer": self.scene.view_layers[0]}

    # -- baking -----------------------------------------------------------------------------------------
    def bake_keys(self, name: str, samples, frames, animated: bool) -> list:
        """Rewrite the copy of ``name``'s shape keys as plain keys keyed with ``samples.weights``; returns the
        names of keys whose weights were split (core.export.weights)."""
        c = self.copies[name]
        key = c.data.shape_keys
        basis, deltas = _plain_deltas(c)
        key.animation_data_clear()                      # drivers and the user's action: replaced by keys
        split, curves = [], {}
        for j, kname in enumerate(samples.names):
            parts = split_weights(samples.weights[:, j])
            for part in parts:
                target = kname + part.suffix
                if part.suffix == NEGATIVE_SUFFIX:
                    target = _unique_key_name(key, target)
                    c.shape_key_add(name=target, from_mix=False)
                _set_key(key.key_blocks[target], basis + part.scale * deltas[j])
                curves[target] = part.weights
            if len(parts) > 1 or parts[0].scale != 1.0:
                split.append(kname)
        self._key_weights(c, key, curves, frames, animated)
        write_float(c.data.vertices, "co", basis)
        return split

    def bake_per_frame(self, name: str, positions: np.ndarray, frames, animated: bool) -> int:
        """Weighted PSD through glTF/FBX: replace the copy's shape keys by one key per frame holding that
        frame's corrected mesh, weight 1 at its frame and 0 at the others; returns the number of keys."""
        c = self.copies[name]
        key = c.data.shape_keys
        basis = read_float(key.reference_key.data, "co", 3).astype(np.float64)
        for kb in list(key.key_blocks)[1:]:           # the frames' keys replace them (same Key datablock)
            c.shape_key_remove(kb)
        curves = {}
        eye = np.eye(len(frames))
        for i, f in enumerate(frames):
            kname = f"{FRAME_KEY_PREFIX}{int(f):05d}"
            kb = c.shape_key_add(name=kname, from_mix=False)
            _set_key(kb, positions[i])
            curves[kname] = eye[i]
        write_float(c.data.vertices, "co", basis)
        self._key_weights(c, key, curves, frames, animated)
        return len(frames)

    def bake_point_cache(self, name: str, positions: np.ndarray, frames) -> str:
        """Alembic with weighted PSD: play the corrected pre-armature mesh from a PC2 point cache (a Mesh Cache
        modifier first in the copy's stack), exact at every frame; returns the cache path."""
        c = self.copies[name]
        path = os.path.join(self.temp_dir(), f"{len(os.listdir(self.temp_dir()))}.pc2")
        write_pc2(path, positions, start_frame=float(frames[0]), sample_rate=1.0)
        mod = c.modifiers.new("ShapeSpace Export Cache", "MESH_CACHE")
        mod.cache_format, mod.filepath, mod.deform_mode = "PC2", path, "OVERWRITE"
        mod.time_mode, mod.play_mode, mod.frame_start = "FRAME", "SCENE", float(frames[0])
        mod.frame_scale, mod.interpolation = 1.0, "LINEAR"
        while c.modifiers[0] != mod:
            c.modifiers.move(list(c.modifiers).index(mod), 0)
        return path

    def _key_weights(self, obj, key, curves: dict, frames, animated: bool) -> None:
        """Key ``curves`` ({key name: weights (f,)}) on the copy's Key (LINEAR), or set a still's values."""
        for kname, w in curves.items():
            key.key_blocks[kname].value = float(w[0])
        if not animated:
            return
        self.created.append(("actions", actions.new_action(key, f"{obj.name}_ShapeKeys")))
        for kname, w in curves.items():
            actions.write_curve(key, actions.shape_key_path(kname), frames, w, interpolation="LINEAR")


def _unique_key_name(key, name: str) -> str:
    out, n = name, 1
    while out in key.key_blocks:
        out, n = f"{name}.{n:03d}", n + 1
    return out


def _set_key(kb, positions) -> None:
    write_float(kb.data, "co", positions)
    kb.slider_min, kb.slider_max = 0.0, 1.0
    kb.mute = False
    kb.vertex_group = ""


def _plain_deltas(obj) -> tuple:
    """Basis (p, 3) and each non-reference key's effective displacement (n, p, 3): ``mask · (key − relative)``,
    as Blender's relative-key evaluation applies it; every key is made relative to the basis."""
    key = obj.data.shape_keys
    ref = key.reference_key
    co = {kb.name: read_float(kb.data, "co", 3).astype(np.float64) for kb in key.key_blocks}
    basis = co[ref.name]
    deltas = []
    for kb in list(key.key_blocks)[1:]:
        rel = kb.relative_key if kb.relative_key is not None else ref
        d = co[kb.name] - co[rel.name]
        if kb.vertex_group:
            mask = group_weight_vector(obj, kb.vertex_group)
            d = d * (mask[:, None] if mask is not None else 0.0)
        deltas.append(d)
        kb.relative_key = ref
    return basis, np.array(deltas).reshape(-1, len(basis), 3)
