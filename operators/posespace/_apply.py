"""The shared flow of the two ways to apply a sculpt (rest-space and post-deformation correctives)."""
from ...bridge import posespace
from ..progress import window_progress
from ..reporting import FAILED, attempt


def apply_active_sculpt(op, context, apply):
    """Apply the active example's sculpt with ``apply(ob, name, progress=…)`` (a bridge verb) under
    window-manager progress, then remove the posed copy if the operator's ``remove_copy`` asks.

    Returns ``(object, example name, result)``, or :data:`~operators.reporting.FAILED` (already reported).
    """
    ob = context.active_object
    st = ob.shapespace_psd
    name = st.examples[st.active_example].name
    with window_progress(context) as progress:
        result = attempt(op, apply, ob, name, progress=progress)
    if result is FAILED:
        return FAILED
    if op.remove_copy:
        posespace.remove_sculpt_copy(ob, name)
    return ob, name, result
