"""Curve inpainting (thesis 9.3): fill a gap of one F-Curve from the covariance of the rest of the animation."""
from __future__ import annotations

import numpy as np

from ...core import facespace as fs
from ...core.errors import ErrorCode
from ...core.facespace.job import inpaint_step
from ...core.facespace.report import InpaintReport
from ...core.result import ShapeSpaceError
from .. import actions
from .readers import integer_frames, refuse_non_finite_keys, refuse_non_finite_samples, tick


def _curve_owner(obj):
    """(ID, action) whose F-Curves animate ``obj``: its shape keys' when it has shape-key animation."""
    key = obj.data.shape_keys if obj.type == "MESH" else None
    if key is not None and actions.active_action(key) is not None:
        return key, actions.active_action(key)
    act = actions.active_action(obj)
    if act is None:
        raise ShapeSpaceError(f"{obj.name!r} has no animation", ErrorCode.NO_ACTION)
    return obj, act


def _sampled_curves(action, target, others, frames, gap, progress) -> np.ndarray:
    """Samples (T, 1 + c) of the target curve and the context curves at ``frames``; the target's known
    samples (outside ``gap``) and every context sample must be finite (refused naming the curve and key)."""
    columns = []
    for i, fc in enumerate([target] + others):
        col = actions.sample_curve(fc, frames)
        known = ~gap if fc is target else np.ones(frames.size, bool)
        if not np.isfinite(col[known]).all():
            skip = (frames[gap][0], frames[gap][-1]) if fc is target and gap.any() else None
            refuse_non_finite_keys(action, [fc], skip=skip)
            refuse_non_finite_samples(action, fc, frames[known], col[known])
        columns.append(col)
        tick(progress, 0.6 * (i + 1) / (1 + len(others)))
    return np.column_stack(columns)


def inpaint_gap(obj, data_path: str, index: int, start: int, end: int, use_other_channels: bool = True,
                progress=None) -> InpaintReport:
    """Fill frames ``start … end`` of one F-Curve from the covariance of the rest of the animation
    (9.3), keying every frame of the gap; the known samples outside stay exactly as they were.

    With ``use_other_channels`` the other curves of the action whose motion correlates with the target's
    condition the fill too (superresolution: a knee from the hips), as many as the animation's length
    can support (:func:`core.facespace.fill_gap`).  Keys of the target inside the gap may be damaged (NaN):
    they are replaced.  ``progress`` (optional) is called with the fraction of the work done."""
    owner, action = _curve_owner(obj)
    curves = actions.fcurves(action, owner)
    target = next((fc for fc in curves if fc.data_path == data_path and fc.array_index == index), None)
    if target is None:
        raise ShapeSpaceError(f"{action.name!r} has no curve {data_path}[{index}]", ErrorCode.MISSING_CURVE)
    frames = integer_frames(action)
    gap = fs.gap_mask(frames, start, end)
    others = [fc for fc in curves if use_other_channels
              and (fc.data_path, fc.array_index) != (target.data_path, target.array_index)]
    X = _sampled_curves(action, target, others, frames, gap, progress)
    values, report = inpaint_step(X, gap)
    tick(progress, 0.95)
    actions.replace_keys_between(target, start, end, frames[gap], values)
    tick(progress, 1.0)
    return report
