"""Mirror Example: add the left↔right mirror of an example (mirrored pose and corrective).

The maths (name and pose flipping, vertex pairing by KD-tree, mirrored displacements) is in
:mod:`core.posespace.mirror`; this module reads and writes Blender data around it.
"""
from __future__ import annotations

from ...core.errors import ErrorCode
from ...core.posespace.mirror import mirror_displacements, mirror_name, mirror_partners, mirror_pose
from ...core.result import ShapeSpaceError
from ..arrays import write_float
from .examples import basis_positions, check_not_editing, example_correctives, new_corrective_key
from .pose import armature_of, readers, settings
from .stored import check_examples, example_pose, find_example, set_example_pose


def _check_mirror_bones(obj, rs) -> None:
    """Mirrored bone readers must point at bones that exist."""
    for r in rs:
        if r.is_bone:
            arm = armature_of(obj)
            if arm is None or mirror_name(r.source) not in arm.pose.bones:
                raise ShapeSpaceError(f"bone {mirror_name(r.source)!r} (the mirror of {r.source!r}) does not exist",
                                      ErrorCode.NO_MIRROR)


def mirror_example(obj, example_name: str, tolerance: float = 1e-4) -> str:
    """Add the left↔right mirror of an example: mirrored pose and corrective (mesh mirrored across local X).

    ``tolerance``: how far a vertex may be from its mirror partner, as a fraction of the mesh size.
    Returns the new example's name.
    """
    check_not_editing(obj)
    st = settings(obj)
    ex = find_example(obj, example_name)
    check_examples(obj)
    rs = readers(obj)
    _check_mirror_bones(obj, rs)
    pose = mirror_pose(rs, example_pose(ex))
    basis = basis_positions(obj)
    partner = mirror_partners(basis, tolerance)
    mirrored = mirror_displacements(example_correctives(obj, [ex])[0], partner)
    key = obj.data.shape_keys
    name = mirror_name(ex.name)
    if name == ex.name or name in key.key_blocks:
        name = ex.name + "_mirror"
    kb = new_corrective_key(obj, name)
    write_float(kb.data, "co", basis + mirrored)
    new = st.examples.add()
    new.name = kb.name
    set_example_pose(new, pose)
    st.active_example = len(st.examples) - 1
    st.revision += 1
    return kb.name
