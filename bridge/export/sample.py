"""Sampling what only drivers and ShapeSpace know, frame by frame, in the user's scene (read only).

Every shape key's *effective* weight — what Blender's evaluation uses: the animated or driven value,
clamped to its slider range, 0 when muted — is read at every frame.  Pose-space correctives come from the
trained deformer at each frame's pose (PSD / Shape-by-Example: example weights; weighted PSD: the
corrected pre-armature mesh, per vertex).  The scene's current frame is restored afterwards; nothing
else is written.
"""
from __future__ import annotations

import re
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from ...core.result import ShapeSpaceError
from .. import posespace
from ..arrays import read_float
from .collect import driven_keys

_KEY_VALUE = re.compile(r'^(?:data\.shape_keys\.)?key_blocks\["((?:[^"\\]|\\.)*)"\]\.value$')


@dataclass
class MeshSamples:
    """One mesh's sampled shape-key weights (and weighted-PSD meshes) over the baked frames.

    Attributes
    ----------
    names : list of str
        Shape keys in key order, the reference key left out.
    weights : ndarray, shape (f, n)
        Effective weight of each key at each frame.
    driven : list of str
        Keys a driver sets.
    posespace : str
        ``""`` or the pose-space method baked (``psd``, ``sbe``, ``wpsd``).
    positions : ndarray, shape (f, p, 3), or None
        Weighted PSD: the corrected mesh before the Armature modifier (object space).
    notes : list of str
    """

    names: list
    weights: np.ndarray
    driven: list = field(default_factory=list)
    posespace: str = ""
    positions: np.ndarray | None = None
    notes: list = field(default_factory=list)


class _PoseSpace:
    """A mesh's trained pose-space deformer and where its outputs go (example keys, driven shape keys)."""

    def __init__(self, obj, names: list):
        self.obj = obj
        self.deformer, self.examples = posespace.trained_deformer(obj)
        self.method = self.deformer.method
        owned = posespace.example_keys(obj)
        self.zeroed = [names.index(n) for n in owned if n in names]        # muted examples, the WPSD key
        self.columns = [names.index(n) for n in self.examples]
        self.driver = posespace.target_driver(obj)
        self.target_columns, self.skipped = self._shape_key_targets(names)

    def _shape_key_targets(self, names: list) -> tuple:
        key = self.obj.data.shape_keys
        cols, skipped = [], []
        for t in posespace.settings(self.obj).targets:
            m = _KEY_VALUE.match(t.data_path)
            own = t.owner == key or t.owner == self.obj
            name = m.group(1).replace('\\"', '"').replace("\\\\", "\\") if m else None
            if own and name in names:
                cols.append(names.index(name))
            else:
                cols.append(None)
                skipped.append(f"{getattr(t.owner, 'name', '?')}.{t.data_path}")
        return cols, skipped

    def apply(self, row: np.ndarray) -> np.ndarray | None:
        """Write this frame's example weights (and shape-key targets) into ``row``; weighted PSD returns the
        corrected pre-armature mesh instead."""
        pose = posespace.read_pose(self.obj)
        row[self.zeroed] = 0.0
        if self.driver is not None:
            for col, value in zip(self.target_columns, self.driver(pose).values()):
                if col is not None:
                    row[col] = value
        if self.method == "wpsd":
            return posespace.pre_armature_positions(self.obj) + self.deformer.evaluate(pose)
        row[self.columns] = self.deformer.weights(pose)
        return None


@contextmanager
def paused_live_preview(objects):
    """Pause pose-space Live Preview on ``objects`` while the export steps through frames (as Bake does), so
    ShapeSpace's own frame handler writes nothing into the user's file; restored afterwards."""
    paused = [ob for ob in objects if hasattr(ob, "shapespace_psd") and ob.shapespace_psd.live_preview]
    for ob in paused:
        ob.shapespace_psd.live_preview = False
    try:
        yield
    finally:
        for ob in paused:
            ob.shapespace_psd.live_preview = True


def has_examples(ob) -> bool:
    """The mesh has pose-space examples (False when ShapeSpace's properties are not registered, as in a bare
    ``bpy`` session: then there are none to read)."""
    return hasattr(ob, "shapespace_psd") and len(posespace.settings(ob).examples) > 0


def _effective_weights(key, ranges: np.ndarray, muted: np.ndarray) -> np.ndarray:
    values = read_float(key.key_blocks, "value", 1).astype(np.float64)[1:]
    values = np.clip(values, ranges[:, 0], ranges[:, 1])
    values[muted] = 0.0
    return values


def _key_layout(key):
    blocks = list(key.key_blocks)[1:]
    ranges = np.array([[kb.slider_min, kb.slider_max] for kb in blocks], dtype=np.float64).reshape(-1, 2)
    muted = np.array([kb.mute for kb in blocks], dtype=bool)
    return [kb.name for kb in blocks], ranges, muted


def sample_meshes(meshes, scene, frames) -> dict:
    """Sample every mesh with shape keys (or pose-space examples) at ``frames``; ``{object name: MeshSamples}``.

    The scene's frame is restored afterwards (whatever happens).
    """
    frames = [int(f) for f in frames]
    jobs = []
    for ob in meshes:
        key = ob.data.shape_keys
        if key is None or len(key.key_blocks) < 2:
            continue
        names, ranges, muted = _key_layout(key)
        ps = _PoseSpace(ob, names) if has_examples(ob) else None
        samples = MeshSamples(names, np.zeros((len(frames), len(names))), driven_keys(ob),
                              ps.method if ps else "")
        if ps is not None and ps.method == "wpsd":
            samples.positions = np.zeros((len(frames), len(ob.data.vertices), 3))
        if ps is not None and ps.skipped:
            samples.notes.append(f"{ob.name}: pose-space targets not baked (not shape keys of the mesh): "
                                 f"{', '.join(ps.skipped)}")
        jobs.append((ob, key, ranges, muted, ps, samples))
    current, subframe = scene.frame_current, scene.frame_subframe
    try:
        for i, f in enumerate(frames):
            scene.frame_set(f)
            for _ob, key, ranges, muted, ps, samples in jobs:
                row = _effective_weights(key, ranges, muted)
                if ps is not None:
                    mesh = ps.apply(row)
                    if mesh is not None:
                        samples.positions[i] = mesh
                samples.weights[i] = row
    finally:
        scene.frame_set(current, subframe=subframe)
    return {ob.name: samples for ob, _, _, _, _, samples in jobs}


def check_pose_space(meshes) -> None:
    """Refuse (before any work) a mesh whose pose-space correctives cannot be trained, naming the problem."""
    for ob in meshes:
        if ob.data.shape_keys is not None and has_examples(ob):
            try:
                posespace.trained_deformer(ob)
            except ShapeSpaceError as exc:
                raise ShapeSpaceError(f"{ob.name}: {exc}", exc.code) from None

