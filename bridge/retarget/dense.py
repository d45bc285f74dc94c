"""Dense performances: an animated mesh (any deformation) read frame by frame, with its landmark pairs.

:func:`mesh_sequence` evaluates the source at every frame; :func:`read_dense_inputs` gathers what
:func:`core.retarget.job.dense_positions` needs to transfer it onto the target's vertices (same topology:
vertex to vertex; else the ``lm_*`` landmark pairs warp it and closest points sample it).
"""
from __future__ import annotations

import bpy
import numpy as np

from ...core.progress import notify
from ...core.retarget.job import LANDMARK_PREFIX, check_landmark_pairs, dense_positions
from ..arrays import read_float
from ..meshes import evaluated_positions, group_weight_vector, vertex_positions

__all__ = ["LANDMARK_PREFIX", "STABLE_GROUP", "landmark_pairs", "mesh_sequence", "read_dense_inputs",
           "dense_source_positions"]

#: Vertex group of the source's vertices that move with the head only (its motion is removed per frame).
STABLE_GROUP = "stable"


def _group_vertices(obj, name):
    """The vertices of ``obj``'s vertex group ``name`` (weight > 0), (k,) int; empty when there is no such group."""
    w = group_weight_vector(obj, name)
    return np.flatnonzero(w > 0) if w is not None else np.zeros(0, dtype=int)


def landmark_pairs(source, target):
    """Corresponding vertices from vertex groups named ``lm_<name>`` on both meshes (one vertex each)."""
    names = sorted(g.name for g in source.vertex_groups if g.name.startswith(LANDMARK_PREFIX)
                   and g.name in target.vertex_groups)
    src, dst = [], []
    for n in names:
        a, b = _group_vertices(source, n), _group_vertices(target, n)
        if a.size and b.size:
            src.append(int(a[0]))
            dst.append(int(b[0]))
    return np.array(src, dtype=int), np.array(dst, dtype=int)


def mesh_sequence(source, scene, frames, progress=None) -> np.ndarray:
    """Evaluated (object-space) positions of ``source`` at each frame, (f, p, 3); ``progress`` per frame.
    The scene gets its current frame back however this ends."""
    current = scene.frame_current
    depsgraph = bpy.context.evaluated_depsgraph_get()
    out = []
    try:
        for k, f in enumerate(frames, start=1):
            scene.frame_set(int(f))
            out.append(evaluated_positions(source, depsgraph).astype(np.float64))
            notify(progress, k / len(frames))
    finally:
        scene.frame_set(current)
    return np.stack(out)


def read_dense_inputs(source, target_model, target, scene, frames, progress=None) -> dict:
    """What :func:`core.retarget.job.dense_positions` needs, read from Blender: the source's evaluated mesh at every
    frame, its neutral (reference shape key, else its mesh vertices — for a cache, as imported), its ``stable``
    group (head motion removed per frame) and the ``lm_*`` landmark pairs; checked before any work."""
    src_lm, dst_lm = landmark_pairs(source, target)
    n_source = len(evaluated_positions(source, bpy.context.evaluated_depsgraph_get()))   # before a long read
    check_landmark_pairs(n_source, target_model.neutral.shape[0], src_lm.size)
    key = source.data.shape_keys
    rest = (read_float(key.reference_key.data, "co", 3) if key is not None else
            vertex_positions(source.data)).astype(np.float64)
    seq = mesh_sequence(source, scene, frames, progress)
    return {"seq": seq, "rest": rest, "stable": _group_vertices(source, STABLE_GROUP), "src_lm": src_lm,
            "dst_lm": dst_lm}


def dense_source_positions(source, target_model, target, scene, frames):
    """The source performance transferred onto the target's vertices: (f, p_t·3) positions
    (:func:`read_dense_inputs` then :func:`core.retarget.job.dense_positions`: vertex to vertex for the same
    topology, else landmark warp and closest points)."""
    return dense_positions(read_dense_inputs(source, target_model, target, scene, frames), target_model)
