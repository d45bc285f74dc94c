"""Progress reporting and cancellation for long computations (foundation; no Blender).

Long core routines take an optional ``progress`` callable, ``progress(fraction: float) -> None`` with
``fraction`` in [0, 1]. A caller cancels the work by raising :class:`Cancelled` from inside that callable
(for example when the artist pressed Esc, or a worker thread's cancel flag is set); core routines never catch
it, so the exception unwinds to the caller before anything is written to Blender.
"""
from __future__ import annotations

from typing import Callable, Optional

ProgressFn = Callable[[float], None]


class Cancelled(Exception):
    """Raised from a progress callable to stop a computation; nothing has been written when it arrives."""


def notify(progress: Optional[ProgressFn], fraction: float) -> None:
    """Call *progress* with *fraction* clipped to [0, 1]; no-op when *progress* is None."""
    if progress is not None:
        progress(min(1.0, max(0.0, float(fraction))))


def scaled(progress: Optional[ProgressFn], start: float, stop: float) -> Optional[ProgressFn]:
    """A progress callable for a sub-task that maps its [0, 1] onto [start, stop] of *progress*.

    Parameters
    ----------
    progress : callable or None
        The parent progress callable.
    start, stop : float
        The parent's fractions at the sub-task's beginning and end, 0 <= start <= stop <= 1.

    Returns
    -------
    callable or None
        None when *progress* is None (so sub-tasks can skip reporting cheaply).
    """
    if progress is None:
        return None
    span = float(stop) - float(start)

    def sub(fraction: float) -> None:
        notify(progress, float(start) + span * min(1.0, max(0.0, float(fraction))))

    return sub
