"""Long computations in a worker thread, with progress and cancellation (foundation; no Blender).

A :class:`BackgroundJob` runs ``work(progress)`` — a pure computation that reports through the
:mod:`core.progress` protocol — in a daemon thread, while the caller (a modal operator's timer on Blender's
main thread) polls :attr:`~BackgroundJob.fraction` and :attr:`~BackgroundJob.done`.  :meth:`~BackgroundJob.cancel`
sets a flag that the next ``progress`` call turns into :class:`~core.progress.Cancelled`, so the work unwinds
before producing anything; the caller writes the result (on its own thread) only when the job finished.

NumPy and SciPy release the GIL inside their kernels, so Blender stays responsive while the worker runs.
The work must not touch Blender data: read everything first, on the main thread, and write afterwards.
"""
from __future__ import annotations

import threading
import time
from typing import Any, Callable

from .progress import Cancelled, ProgressFn

__all__ = ["BackgroundJob"]


class BackgroundJob:
    """``work(progress)`` in a worker thread, polled by the caller.

    Parameters
    ----------
    work : callable
        ``work(progress) -> value``; calls ``progress(fraction)`` with fractions in [0, 1] as it goes.
    name : str
        The thread's name.

    Attributes
    ----------
    reported : list of float
        Every fraction ``work`` reported, in order (what a progress bar showed).
    """

    def __init__(self, work: Callable[[ProgressFn], Any], name: str = "ShapeSpace job") -> None:
        self._work = work
        self._cancel = threading.Event()
        self._finished = threading.Event()
        self._lock = threading.Lock()
        self._value: Any = None
        self._error: BaseException | None = None
        self._fraction = 0.0
        self.reported: list = []
        self.started_at: float | None = None
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)

    # ---------------------------------------------------------------- worker side
    def _progress(self, fraction: float) -> None:
        if self._cancel.is_set():
            raise Cancelled()
        with self._lock:
            self.reported.append(float(fraction))
            self._fraction = max(self._fraction, min(1.0, max(0.0, float(fraction))))

    def _run(self) -> None:
        try:
            self._value = self._work(self._progress)
            if self._cancel.is_set():         # cancelled after the last progress call: drop the result
                raise Cancelled()
        except BaseException as exc:        # handed to the caller by result()
            self._error = exc
        finally:
            self._finished.set()

    # ---------------------------------------------------------------- caller side
    def start(self) -> BackgroundJob:
        """Start the worker thread (once); returns the job."""
        self.started_at = time.perf_counter()
        self._thread.start()
        return self

    def run_here(self) -> Any:
        """Run the work in the calling thread instead (scripts, redo); returns :meth:`result`."""
        self.started_at = time.perf_counter()
        self._run()
        return self.result()

    @property
    def fraction(self) -> float:
        """The largest fraction reported so far, in [0, 1] (1 once the work finished without error)."""
        with self._lock:
            return 1.0 if self._finished.is_set() and self._error is None else self._fraction

    @property
    def done(self) -> bool:
        """Whether the work has ended (finished, failed or cancelled)."""
        return self._finished.is_set()

    @property
    def cancelled(self) -> bool:
        """Whether :meth:`cancel` was called."""
        return self._cancel.is_set()

    def cancel(self) -> None:
        """Ask the work to stop: its next ``progress`` call raises :class:`~core.progress.Cancelled`."""
        self._cancel.set()

    def wait(self, timeout: float | None = None) -> bool:
        """Block until the work ended (or ``timeout`` seconds passed); returns :attr:`done`."""
        return self._finished.wait(timeout)

    def elapsed(self) -> float:
        """Seconds since :meth:`start` (0 before)."""
        return 0.0 if self.started_at is None else time.perf_counter() - self.started_at

    def result(self) -> Any:
        """The work's value; re-raises its exception (:class:`~core.progress.Cancelled` when cancelled).

        Call only once :attr:`done`.
        """
        if not self._finished.is_set():
            raise RuntimeError("the job has not finished")
        if self._error is not None:
            raise self._error
        return self._value
