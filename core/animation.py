"""F-Curve maths: sampling keyframed curves and frame-rate conversion.

Blender's F-Curves are piecewise: each key's ``interpolation`` governs the
segment that starts at it.  :func:`sample_keys` evaluates the ``CONSTANT`` and
``LINEAR`` cases exactly and vectorised; the bridge falls back to Blender's
own ``FCurve.evaluate`` for Bézier and easing segments or curve modifiers.
:func:`frames_to_seconds` / :func:`seconds_to_frames` convert between scene
frames and capture time.  Key reduction (fewest keys within a tolerance) is
:mod:`core.keyreduce`.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .result import ShapeSpaceError

__all__ = ["CONSTANT", "LINEAR", "sample_keys", "frames_to_seconds", "seconds_to_frames"]

CONSTANT = 0
LINEAR = 1


def sample_keys(key_frames: ArrayLike, key_values: ArrayLike, interpolation: ArrayLike, frames: ArrayLike,
                extrapolate_linear: bool = False) -> np.ndarray:
    """Evaluate one curve of CONSTANT/LINEAR keys at ``frames``.

    Parameters
    ----------
    key_frames : array_like, shape (m,)
        Strictly increasing key times (frames, may be fractional).
    key_values : array_like, shape (m,)
    interpolation : array_like of int, shape (m,)
        :data:`CONSTANT` or :data:`LINEAR` per key (governs the segment after it).
    frames : array_like, shape (f,)
        Where to sample.
    extrapolate_linear : bool
        Blender's "Linear Extrapolation": continue the first/last segment's
        slope instead of holding the end values.

    Returns
    -------
    ndarray, shape (f,)
    """
    x = np.asarray(key_frames, dtype=np.float64)
    y = np.asarray(key_values, dtype=np.float64)
    mode = np.asarray(interpolation, dtype=np.int64)
    t = np.asarray(frames, dtype=np.float64)
    if x.ndim != 1 or x.shape != y.shape or x.shape != mode.shape:
        raise ShapeSpaceError(
            f"key_frames, key_values and interpolation must be 1-D of equal length; got "
            f"{x.shape}, {y.shape}, {mode.shape}", "shape")
    if x.size == 0:
        raise ShapeSpaceError("a curve needs at least one key", "empty_curve")
    if x.size > 1 and np.any(np.diff(x) <= 0):
        raise ShapeSpaceError("key_frames must be strictly increasing", "unsorted")
    if x.size == 1:
        return np.full(t.shape, y[0])
    seg = np.clip(np.searchsorted(x, t, side="right") - 1, 0, x.size - 2)
    x0, x1, y0, y1 = x[seg], x[seg + 1], y[seg], y[seg + 1]
    frac = (t - x0) / (x1 - x0)
    lin = y0 + (y1 - y0) * frac
    out = np.where(mode[seg] == LINEAR, lin, np.where(t >= x1, y1, y0))
    before, after = t < x[0], t > x[-1]
    if extrapolate_linear:
        s0 = (y[1] - y[0]) / (x[1] - x[0]) if mode[0] == LINEAR else 0.0
        # Blender: each end extrapolates by its own key's interpolation (a CONSTANT end key holds)
        s1 = (y[-1] - y[-2]) / (x[-1] - x[-2]) if mode[-1] == LINEAR else 0.0
        out = np.where(before, y[0] + s0 * (t - x[0]), out)
        out = np.where(after, y[-1] + s1 * (t - x[-1]), out)
    else:
        out = np.where(before, y[0], out)
        out = np.where(after, y[-1], out)
    return out


def frames_to_seconds(frames: ArrayLike, fps: float, fps_base: float = 1.0,
                      frame_offset: float = 0.0) -> np.ndarray:
    """Scene frames → seconds (Blender: ``fps / fps_base`` frames per second)."""
    if fps <= 0 or fps_base <= 0:
        raise ShapeSpaceError(f"fps must be positive, got {fps}/{fps_base}", "fps")
    return (np.asarray(frames, dtype=np.float64) - frame_offset) * fps_base / fps


def seconds_to_frames(seconds: ArrayLike, fps: float, fps_base: float = 1.0,
                      frame_offset: float = 0.0) -> np.ndarray:
    """Seconds → scene frames (inverse of :func:`frames_to_seconds`)."""
    if fps <= 0 or fps_base <= 0:
        raise ShapeSpaceError(f"fps must be positive, got {fps}/{fps_base}", "fps")
    return np.asarray(seconds, dtype=np.float64) * fps / fps_base + frame_offset
