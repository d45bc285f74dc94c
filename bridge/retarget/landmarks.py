"""Landmark pairs between two meshes: vertex groups ``lm_<name>`` holding one vertex each, placed by hand
(:func:`add_landmark`, :func:`selected_vertex`) or found from the shapes both meshes share
(:func:`landmarks_from_shapes`)."""
from __future__ import annotations

import numpy as np

from ...core.result import ShapeSpaceError
from ...core.retarget import peak_landmarks
from .. import shapekeys
from .dense import LANDMARK_PREFIX
from .mapping import channel_mapping

__all__ = ["add_landmark", "landmarks_from_shapes", "selected_vertex"]


def add_landmark(obj, name: str, vertex: int) -> str:
    """(Re)define the landmark vertex group ``lm_<name>`` as the single vertex ``vertex``."""
    group_name = name if name.startswith(LANDMARK_PREFIX) else LANDMARK_PREFIX + name
    group = obj.vertex_groups.get(group_name) or obj.vertex_groups.new(name=group_name)
    group.remove(list(range(len(obj.data.vertices))))
    group.add([int(vertex)], 1.0, "REPLACE")
    return group.name


def landmarks_from_shapes(source, target) -> list:
    """Create landmark pairs from the shapes both meshes share (by mapped name): each pair's vertices are
    the ones that shape moves most on each mesh (chin for jawOpen, lids for eyeBlink, …).  Existing
    ``lm_auto_*`` groups are replaced; hand-placed landmarks are kept.  Returns the group names."""
    for ob in (source, target):
        if ob.type != "MESH" or ob.data.shape_keys is None or len(ob.data.shape_keys.key_blocks) < 2:
            raise ShapeSpaceError(f"{ob.name!r} has no shape keys to find landmarks from", "no_shape_keys")
    model_s = shapekeys.read_blendshape_model(source)
    model_t = shapekeys.read_blendshape_model(target)
    mapping = channel_mapping(target, model_s.names, model_t.names)
    src, dst, used = peak_landmarks(model_s.deltas, model_t.deltas, [(i, j) for i, j, _, _ in mapping])
    if src.size < 3:
        raise ShapeSpaceError(f"only {src.size} shared shapes have a clear peak vertex; place landmarks by hand",
                              "too_few_landmarks")
    for ob in (source, target):
        for group in [g for g in ob.vertex_groups if g.name.startswith(LANDMARK_PREFIX + "auto_")]:
            ob.vertex_groups.remove(group)
    names = []
    for a, b, (_, j) in zip(src, dst, used):
        name = "auto_" + model_t.names[j]
        add_landmark(source, name, int(a))
        names.append(add_landmark(target, name, int(b)))
    return names


def selected_vertex(obj):
    """The single selected vertex of a mesh (object mode data), or None."""
    sel = np.zeros(len(obj.data.vertices), dtype=bool)
    obj.data.vertices.foreach_get("select", sel)
    idx = np.flatnonzero(sel)
    return int(idx[0]) if idx.size == 1 else None
