"""Push one sculpt into several correctives split by vertex-group masks, and into its mirror.

The example's posed sculpt is inverted to a rest-space corrective δ at the current pose (as Apply Sculpt does),
then split by the masks, normalised per vertex where they overlap
(:func:`core.posespace.finalshape.split_by_masks`), so the parts add up to δ exactly and, skinning acting per
vertex, the parts' keys at 1 give the sculpt at the pose.  Each part becomes a shape key
``<example>.<group>`` (value 0, wide sliders) for the rigger to drive — Blender Studio's "push to several
keys".  Sculpted vertices that no mask covers are refused by index, or go into ``<example>.remainder``.
With ``mirror`` every part's mirror (through the mesh's mirror map, :mod:`bridge.symmetry`) is added too,
named by the other side (``….Shoulder.L`` → ``….Shoulder.R``, else ``…_mirror``).
"""
from __future__ import annotations

import numpy as np

from ...core import symmetry as core_sym
from ...core.errors import ErrorCode
from ...core.posespace.finalshape import split_by_masks, uncovered_vertices
from ...core.result import ShapeSpaceError
from .. import symmetry
from ..arrays import write_float
from ..meshes import group_weight_vector, vertex_groups
from .correctives import (
    basis_positions,
    check_finite_positions,
    check_not_editing,
    check_topology,
    new_corrective_key,
    pre_armature_positions,
)
from .inversion import invert, sculpt_positions_of
from .pose import settings
from .stored import check_examples, find_example

__all__ = ["push_sculpt_masked", "REMAINDER"]

#: Suffix of the key that takes the sculpted vertices no mask covers.
REMAINDER = "remainder"


def _masks(obj, groups) -> np.ndarray:
    """(G, p) weights of the named vertex groups (0 where a vertex is not in the group)."""
    if not groups:
        raise ShapeSpaceError("name at least one vertex group to split the sculpt by", ErrorCode.EMPTY)
    if len(set(groups)) != len(groups):
        raise ShapeSpaceError("a vertex group is named twice", ErrorCode.DUPLICATE_NAME)
    missing = [g for g in groups if g not in obj.vertex_groups]
    if missing:
        raise ShapeSpaceError(f"{obj.name!r} has no vertex group {missing[0]!r}", ErrorCode.MISSING_GROUP)
    cache = vertex_groups(obj)
    return np.clip(np.stack([group_weight_vector(obj, g, cache) for g in groups]), 0.0, None)


def _names(ex_name: str, groups, remainder: bool, mirror: bool) -> list:
    """[(key name, source part index or ("mirror", k))] of every key the push makes."""
    base = [f"{ex_name}.{g}" for g in groups] + ([f"{ex_name}.{REMAINDER}"] if remainder else [])
    out = [(n, k) for k, n in enumerate(base)]
    if mirror:
        for k, n in enumerate(base):
            other = core_sym.counterpart_name(n) or f"{n}_mirror"
            out.append((other, ("mirror", k)))
    seen = {}
    for n, src in out:
        if n in seen:
            raise ShapeSpaceError(f"key {n!r} would be made twice (the mirror of one part is another part): push "
                                  "one side's masks with Mirror, or both sides without it", ErrorCode.DUPLICATE_NAME)
        seen[n] = src
    return out


def push_sculpt_masked(obj, example_name: str, groups, mirror: bool = False, remainder: bool = False,
                       sculpt_positions=None, replace: bool = False, progress=None) -> list:
    """Invert the example's sculpt at the current pose and store it split by vertex-group masks.

    ``groups``: vertex-group names (masks).  ``remainder``: put sculpted vertices no mask covers into
    ``<example>.remainder`` (else they are refused, listed by index).  ``mirror``: add every part's mirror.
    ``sculpt_positions`` (p, 3) object space; default: the example's posed copy.  ``replace``: overwrite
    keys of the same names made by an earlier push (never an example's own key).  ``progress``: called with
    the fraction done while inverting through Blender's own evaluation.
    Returns the names of the keys made.  Nothing is written when anything is refused.
    """
    check_not_editing(obj)
    check_topology(obj)
    ex = find_example(obj, example_name)
    check_examples(obj)
    groups = [str(g) for g in groups]
    masks = _masks(obj, groups)
    sculpt_positions = sculpt_positions_of(obj, ex, sculpt_positions)
    plan = _names(ex.name, groups, remainder, mirror)
    key = obj.data.shape_keys
    examples = {e.name for e in settings(obj).examples}
    for n, _ in plan:
        if n in examples:
            raise ShapeSpaceError(f"key {n!r} is a pose-space example's corrective: rename the vertex group",
                                  ErrorCode.OVERWRITE)
        if key is not None and n in key.key_blocks and not replace:
            raise ShapeSpaceError(f"shape key {n!r} exists already: remove it, or push with Replace",
                                  ErrorCode.OVERWRITE)
    basis = basis_positions(obj)
    result = invert(obj, pre_armature_positions(obj), sculpt_positions, progress)
    delta = result.corrective
    check_finite_positions(delta, f"the inverted corrective of {ex.name!r}")
    size = float(np.linalg.norm(np.ptp(basis, axis=0))) or 1.0
    uncovered = uncovered_vertices(delta, masks, size)
    if uncovered.size and not remainder:
        shown = ", ".join(str(int(v)) for v in uncovered[:12]) + (" …" if uncovered.size > 12 else "")
        raise ShapeSpaceError(f"the masks {', '.join(groups)} do not cover {uncovered.size} sculpted vertices "
                              f"({shown}): add them to a mask, or push with Remainder", ErrorCode.UNCOVERED)
    parts, rest = split_by_masks(delta, masks)
    deltas = list(parts) + ([rest] if remainder else [])
    if mirror:
        mmap, _ = symmetry.map_for(obj)
        mirrored = []
        for d in deltas:
            res = core_sym.mirror_delta(d, mmap)
            lost = res.diagnostics.get("lost_vertices", [])
            if lost:
                raise ShapeSpaceError(f"{len(lost)} sculpted vertices have no mirror vertex (first: {lost[:8]}): "
                                      "build a mirror map (Check Rig ▸ Mirror Map) or push without Mirror",
                                      ErrorCode.NOT_SYMMETRIC)
            mirrored.append(res.value)
    made = []
    for n, src in plan:
        d = mirrored[src[1]] if isinstance(src, tuple) else deltas[src]
        kb = key.key_blocks.get(n) if key is not None else None
        if kb is None:
            kb = new_corrective_key(obj, n)
            key = obj.data.shape_keys
        write_float(kb.data, "co", basis + d)
        made.append(kb.name)
    obj.data.update()
    return made
