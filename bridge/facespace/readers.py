"""Readers shared by the face-space verbs: the rig as a linear model, its animation sampled at whole frames, and
the refusals of NaN or infinite keys and frames (naming the curve and the frame)."""
from __future__ import annotations

import numpy as np

from ...core.errors import ErrorCode
from ...core.result import ShapeSpaceError
from .. import actions, shapekeys

#: Longest animation (in frames) the face-space tools sample.
MAX_FRAMES = 1_000_000
_FLOAT32_MAX = float(np.finfo(np.float32).max)


def linear_model(obj):
    """The rig as a :class:`BlendshapeModel`, refusing in-betweens and combinations (correctives are
    not faces: representations and statistics are about the primary sliders)."""
    model = shapekeys.read_blendshape_model(obj)
    if not model.is_linear:
        raise ShapeSpaceError("the rig has in-between or combination shapes: face-space tools work on its "
                              "primary sliders only; use a copy without them", ErrorCode.NONLINEAR)
    if model.n_targets == 0:
        raise ShapeSpaceError(f"{obj.name!r} has no shape keys besides its reference key", ErrorCode.NO_TARGETS)
    return model


def tick(progress, fraction: float) -> None:
    """Report ``fraction`` (0 … 1) of the work done to ``progress`` (a callable, or None)."""
    if progress is not None:
        progress(fraction)


def _curve_name(fc) -> str:
    """How a message names an F-Curve: ``key_blocks["jawOpen"].value`` or ``location[1]``."""
    return fc.data_path if fc.data_path.startswith("key_blocks[") else f"{fc.data_path}[{fc.array_index}]"


def refuse_non_finite_frames(action, fc, kx) -> None:
    """Refuse keys of ``fc`` on NaN or infinite frames ``kx`` (they corrupt the action's frame range)."""
    bad = ~np.isfinite(kx)
    if bad.any():
        raise ShapeSpaceError(f"action {action.name!r}: curve {_curve_name(fc)} has a keyframe at a non-finite "
                              f"frame ({kx[bad][0]}); fix or delete that key", ErrorCode.NON_FINITE)


def refuse_non_finite_keys(action, curves, skip=None) -> None:
    """Refuse a curve with a keyframe on a NaN or infinite frame or with such a value, naming the action, the
    curve and the frame.  ``skip`` = (start, end): values of keys on those frames are not checked (they are
    being replaced).  Handles are judged by what the curve evaluates to (:func:`refuse_non_finite_samples`)."""
    for fc in curves:
        kx, ky, _ = actions.read_curve(fc)
        refuse_non_finite_frames(action, fc, kx)
        bad = ~np.isfinite(ky) | (np.abs(ky) >= _FLOAT32_MAX)    # Blender stores an infinite key as ±FLT_MAX
        if skip is not None:
            bad &= ~((kx >= skip[0]) & (kx <= skip[1]))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ShapeSpaceError(f"action {action.name!r}: curve {_curve_name(fc)} has a non-finite keyframe "
                                  f"(value {ky[i]:g}) at frame {kx[i]:g}; fix or delete that key", ErrorCode.NON_FINITE)


def refuse_non_finite_samples(action, fc, frames, values, label: str = None) -> None:
    """Refuse samples ``values`` (f,) of ``fc`` (or, without a curve, of the value ``label``) that are not
    finite, naming the curve and the first such frame."""
    bad = ~np.isfinite(values)
    if bad.any():
        frame = frames[int(np.flatnonzero(bad)[0])]
        what = f"curve {_curve_name(fc)} of action {action.name!r}" if fc is not None else label
        raise ShapeSpaceError(f"{what} evaluates to {values[bad][0]} at frame {frame:g}: fix the curve (a damaged "
                              "key or handle near that frame, or a modifier)", ErrorCode.NON_FINITE)


def integer_frames(action) -> np.ndarray:
    """Every whole frame of ``action``'s frame range (its keys checked to lie on finite frames)."""
    for fc in actions.action_fcurves(action):
        refuse_non_finite_frames(action, fc, actions.read_curve(fc)[0])
    first, last = actions.frame_range(action)
    if not (np.isfinite(first) and np.isfinite(last)) or last - first > MAX_FRAMES:
        raise ShapeSpaceError(f"action {action.name!r} spans frames {first:g}–{last:g}: more than {MAX_FRAMES} "
                              "frames", ErrorCode.TOO_LARGE)
    return np.arange(np.ceil(first), np.floor(last) + 1)


def animation_weights(obj, names, action=None, min_frames: int = 1):
    """Values of the shape keys ``names`` in ``action`` (default: the rig's own) at every integer frame of
    the action, (f, n), and the frames.  Each value is clamped to its slider's range, as Blender applies it
    (a curve overshooting the range does not move the face further).  A NaN or infinite keyframe (or value)
    is refused, naming the curve and the frame, and so is an action of fewer than ``min_frames`` frames."""
    key = obj.data.shape_keys
    action = action or actions.active_action(key)
    if action is None:
        raise ShapeSpaceError(f"{obj.name!r} has no shape-key animation; choose an action", ErrorCode.NO_ACTION)
    curves = actions.shape_key_curves(obj, action)
    if not curves:
        raise ShapeSpaceError(f"action {action.name!r} animates none of {obj.name!r}'s shape keys",
                              ErrorCode.NO_CHANNELS)
    refuse_non_finite_keys(action, [curves[n] for n in names if n in curves])
    frames = integer_frames(action)
    if frames.size < min_frames:
        raise ShapeSpaceError(f"action {action.name!r} spans {frames.size} frame(s): this needs at least "
                              f"{min_frames}", ErrorCode.TOO_FEW)
    W = actions.sample_shape_keys(obj, names, frames, action)
    for j, name in enumerate(names):
        refuse_non_finite_samples(action, curves.get(name), frames, W[:, j], f"shape key {name!r} of {obj.name!r}")
    blocks = key.key_blocks
    lo = np.array([blocks[n].slider_min for n in names], dtype=np.float64)
    hi = np.array([blocks[n].slider_max for n in names], dtype=np.float64)
    return np.clip(W, lo, hi), frames


