"""Mirror Example: add the left↔right mirror of an example (mirrored pose and corrective).

The maths (name and pose flipping, vertex pairing by KD-tree, mirrored displacements) is in
:mod:`core.posespace.mirror`; this module reads and writes Blender data around it.  The vertex pairing is the
mesh's stored mirror map (Rig ▸ Symmetry ▸ Build Mirror Map, :mod:`..symmetry`) when it has one that is fresh
and readable, so pose-space examples mirror exactly as the symmetry tools do (also on a mesh mirrored by
topology); otherwise today's position map across local X.
"""
from __future__ import annotations

import numpy as np

from ...core import symmetry as core_sym
from ...core.errors import ErrorCode
from ...core.posespace.mirror import mirror_displacements, mirror_name, mirror_partners, mirror_pose
from ...core.result import ShapeSpaceError, Status
from .. import symmetry
from ..arrays import write_float
from .correctives import basis_positions, check_not_editing, example_correctives, new_corrective_key
from .pose import armature_of, readers, settings
from .stored import check_examples, example_pose, find_example, pin_wpsd_distance, set_example_pose


def _check_mirror_bones(obj, rs) -> None:
    """Mirrored bone readers must point at bones that exist."""
    for r in rs:
        if r.is_bone:
            arm = armature_of(obj)
            if arm is None or mirror_name(r.source) not in arm.pose.bones:
                raise ShapeSpaceError(f"bone {mirror_name(r.source)!r} (the mirror of {r.source!r}) does not exist",
                                      ErrorCode.NO_MIRROR)


def stored_map(obj) -> core_sym.MirrorMap | None:
    """The mesh's stored mirror map when there is one and it is fresh and readable, else None (a stale or damaged
    map is not used: Check Rig and the Rig panel name it)."""
    if not symmetry.has_map(obj):
        return None
    try:
        return symmetry.load_map(obj)
    except ShapeSpaceError:
        return None


def mirrored_corrective(obj, delta: np.ndarray, basis: np.ndarray, tolerance: float = 1e-4) -> np.ndarray:
    """The mirror of a corrective ``delta`` (p, 3): through the stored mirror map (:func:`stored_map`;
    ``Δ'[v] = R Δ[m(v)]``, refused when a moving vertex has no mirror in it), else through the position map
    across local X within ``tolerance`` (refused when some vertex has no partner)."""
    mmap = stored_map(obj)
    if mmap is None:
        return mirror_displacements(delta, mirror_partners(basis, tolerance))
    res = core_sym.mirror_delta(delta, mmap)
    if res.status != Status.OK:
        lost = res.diagnostics["lost_vertices"]
        raise ShapeSpaceError(f"{len(lost)} moving vertices of the corrective have no mirror in {obj.name!r}'s "
                              f"mirror map (first: {lost[:5]}): rebuild the map (Rig ▸ Symmetry ▸ Build Mirror "
                              "Map) so it covers them", ErrorCode.NOT_SYMMETRIC)
    return res.value


def mirror_example(obj, example_name: str, tolerance: float = 1e-4) -> str:
    """Add the left↔right mirror of an example: mirrored pose and corrective.

    The corrective is mirrored through the mesh's stored mirror map when it has a fresh one, else across local
    X by position, ``tolerance`` being how far a vertex may be from its mirror partner, as a fraction of the
    mesh size (:func:`mirrored_corrective`).  Returns the new example's name.
    """
    check_not_editing(obj)
    st = settings(obj)
    ex = find_example(obj, example_name)
    check_examples(obj)
    rs = readers(obj)
    _check_mirror_bones(obj, rs)
    pose = mirror_pose(rs, example_pose(ex))
    basis = basis_positions(obj)
    mirrored = mirrored_corrective(obj, example_correctives(obj, [ex])[0], basis, tolerance)
    key = obj.data.shape_keys
    name = mirror_name(ex.name)
    if name == ex.name or name in key.key_blocks:
        name = ex.name + "_mirror"
    kb = new_corrective_key(obj, name)
    write_float(kb.data, "co", basis + mirrored)
    pin_wpsd_distance(st)
    new = st.examples.add()
    new.name = kb.name
    set_example_pose(new, pose)
    st.active_example = len(st.examples) - 1
    st.revision += 1
    return kb.name
