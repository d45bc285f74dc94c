"""Which frames an export bakes: the actions' full range (not the scene's), or the range asked for."""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..errors import ErrorCode
from ..result import ShapeSpaceError
from ..validate import finite_scalar

__all__ = ["export_range", "sample_frames"]

#: Longest take an export bakes (frames): 10 minutes at 120 fps.
MAX_FRAMES = 72_000


def export_range(action_ranges: Sequence[tuple[float, float]], scene_range: tuple[int, int],
                 override: Sequence[float] | None = None) -> tuple[int, int]:
    """The integer frame range to bake and export.

    Retargeting writes actions that may run past the scene's range (the scene stays at 1–160 while the
    action runs 2–335); an export that used the scene range would stop half-way.  So the default is the
    union of the exported objects' actions, widened to whole frames: ``[⌊min start⌋, ⌈max end⌉]``.

    Parameters
    ----------
    action_ranges : sequence of (float, float)
        (first, last) keyed frame of every action that animates an exported object (its transform, its
        shape keys, its armature).  Empty: nothing is animated.
    scene_range : (int, int)
        The scene's (frame_start, frame_end), used when no action animates anything.
    override : (float, float), optional
        An explicit range (``--frame-range A B``); must be whole frames with A ≤ B.

    Returns
    -------
    (int, int)
        First and last frame, inclusive.
    """
    if override is not None:
        if len(override) != 2:
            raise ShapeSpaceError(f"a frame range is two frames (A B), got {list(override)}", ErrorCode.USAGE)
        a, b = (finite_scalar(v, "frame") for v in override)
        if a != int(a) or b != int(b):
            raise ShapeSpaceError(f"frame range {a:g} {b:g}: use whole frames", ErrorCode.RANGE)
        if a > b:
            raise ShapeSpaceError(f"frame range {a:g} {b:g}: the first frame is after the last", ErrorCode.RANGE)
        start, end = int(a), int(b)
    elif action_ranges:
        lo = min(finite_scalar(r[0], "action start") for r in action_ranges)
        hi = max(finite_scalar(r[1], "action end") for r in action_ranges)
        start, end = int(math.floor(lo)), int(math.ceil(hi))
    else:
        start, end = int(scene_range[0]), int(scene_range[1])
        if start > end:
            raise ShapeSpaceError(f"the scene's frame range {start}–{end} is empty", ErrorCode.RANGE)
    if end - start + 1 > MAX_FRAMES:
        raise ShapeSpaceError(f"frame range {start}–{end} has {end - start + 1} frames; the limit is {MAX_FRAMES}",
                              ErrorCode.TOO_LARGE)
    return start, end


def sample_frames(start: int, end: int, count: int) -> np.ndarray:
    """``count`` whole frames spread evenly over [start, end], both ends included (fewer if the range is
    shorter), int64 (n,)."""
    n = max(1, min(int(count), int(end) - int(start) + 1))
    return np.unique(np.round(np.linspace(int(start), int(end), n)).astype(np.int64))
