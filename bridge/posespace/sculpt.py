"""Apply Sculpt (thesis 7.2.1): pull an example's posed sculpt back to rest space and store it in its key.

The inversion itself is :mod:`.inversion`; the sculpt is also kept as the example's final shape
(:mod:`.finalshape`).
"""
from __future__ import annotations

from ...core.posespace.inversion import InversionResult
from ..arrays import write_float
from .correctives import (
    basis_positions,
    check_finite_positions,
    check_not_editing,
    check_topology,
    pre_armature_positions,
)
from .finalshape import store_final_shape, touched
from .inversion import invert, sculpt_positions_of
from .pose import settings
from .stored import check_examples, find_example


def apply_example(obj, example_name: str, sculpt_positions=None, progress=None) -> InversionResult:
    """Invert the example's sculpt to rest space and store it in the example's shape key.

    ``sculpt_positions`` (p, 3) in ``obj``'s object space; default: the sculpt copy's vertices (refused while
    the copy is in Edit Mode).  ``progress``: called with an estimated fraction done while inverting
    through Blender's own evaluation (for a progress display).
    Returns the core ``InversionResult`` (``corrective``, ``residual``, status).  The sculpt is also kept as
    the example's final shape (:mod:`.finalshape`), so the corrective can be re-inverted after rig changes.
    """
    check_not_editing(obj)
    check_topology(obj)
    st = settings(obj)
    ex = find_example(obj, example_name)
    check_examples(obj)
    sculpt_positions = sculpt_positions_of(obj, ex, sculpt_positions)
    basis = basis_positions(obj)
    result = invert(obj, pre_armature_positions(obj), sculpt_positions, progress)
    check_finite_positions(result.corrective, f"the inverted corrective of {ex.name!r}")
    idx = touched(obj, result.corrective)
    key = obj.data.shape_keys
    write_float(key.key_blocks[example_name].data, "co", basis + result.corrective)
    store_final_shape(obj, ex, idx, sculpt_positions[idx])     # the sculpt survives rig changes (re-invert)
    obj.data.update()
    st.revision += 1
    return result
