"""A live stream resampled onto scene frames as it arrives: what a recorded take keys.

The offline retarget resamples a capture onto the scene's frames by linear
interpolation in time (:func:`core.retarget.resample`): with the capture's
times ``t`` shifted to start at 0, scene frame ``start + k`` takes the capture
at ``t = k / rate``, for every ``k`` up to ``⌊t_last · rate + 10⁻⁹⌋``.
:class:`SceneResampler` does the same incrementally: each new sample emits the
scene frames that now lie inside the stream, interpolated between the two
samples around them — so a recorded take is the offline resample of the same
frames, sample for sample.

A forward jump of the source clock longer than :data:`MAX_FILL_SECONDS` (Live
Link Face re-syncing its timecode, Face Cap's time tag going from 0 to the
real time, a phone paused for minutes) is not a gap to fill: interpolating it
would key every scene frame of the jump with made-up motion.
:meth:`SceneResampler.is_jump` tells the recorder to start a new take there,
and :meth:`SceneResampler.push` refuses such a sample instead of filling.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ErrorCode
from ..result import ShapeSpaceError
from ..validate import finite_scalar, positive

__all__ = ["SceneResampler", "MAX_FILL_SECONDS"]

#: Longest forward step of the source clock that is filled by interpolation (lost packets, a short network
#: stall: a few frames); a longer one is a jump of the clock, which starts a new take.
MAX_FILL_SECONDS = 0.25


class SceneResampler:
    """Turn ``(time, vector)`` samples into ``(scene frame, vector)`` samples at the scene rate.

    Parameters
    ----------
    rate : float
        Scene frames per second (``fps / fps_base``).
    start_frame : float
        The scene frame of the first sample.
    max_gap : float
        Longest step between samples, in seconds, that is filled (see :data:`MAX_FILL_SECONDS`).
    """

    def __init__(self, rate: float, start_frame: float = 1.0, max_gap: float = MAX_FILL_SECONDS) -> None:
        self.rate = positive(rate, "rate")
        self.start_frame = finite_scalar(start_frame, "start_frame")
        self.max_gap = positive(max_gap, "max_gap")
        self.t0 = None
        self.start_time = None
        self._t = None
        self._v = None
        self.next_k = 0

    @property
    def last_time(self) -> float | None:
        """Source time of the last accepted sample (None before the first)."""
        return None if self.t0 is None else self.t0 + self._t

    @property
    def frames_emitted(self) -> int:
        """How many scene frames have been emitted."""
        return self.next_k

    @property
    def next_frame(self) -> float:
        """The scene frame the next emitted sample would take (after the last one emitted)."""
        return self.start_frame + self.next_k

    def is_jump(self, time: float) -> bool:
        """Whether a sample at source ``time`` lies more than ``max_gap`` after the last one (not to be filled)."""
        return self.t0 is not None and float(time) - self.last_time > self.max_gap

    def push(self, time: float, vector: ArrayLike) -> list:
        """Add a sample; returns ``[(scene frame, vector (n,))]`` for the scene frames it completes.

        Samples must come in increasing time; a sample not later than the previous one is ignored.

        Raises
        ------
        ShapeSpaceError
            ``range`` for a sample more than ``max_gap`` after the previous one (:meth:`is_jump`): nothing is
            emitted; the caller starts a new take (a new resampler) there.
        """
        if self.is_jump(time):
            raise ShapeSpaceError(f"the source's clock jumped {float(time) - self.last_time:.3g} s forward (more "
                                  f"than {self.max_gap:g} s): start a new take there, the gap is not filled",
                                  ErrorCode.RANGE)
        v = np.asarray(vector, dtype=np.float64)
        if self.t0 is None:
            self.t0, self.start_time = float(time), float(time)
            self._t, self._v = 0.0, v.copy()
            self.next_k = 1
            return [(self.start_frame, v.copy())]
        t = float(time) - self.t0
        if not t > self._t:
            return []
        last_k = int(np.floor(t * self.rate + 1e-9))
        out = []
        for k in range(self.next_k, last_k + 1):
            s = k / self.rate
            if s >= t:
                value = v.copy()
            else:
                slope = (v - self._v) / (t - self._t)
                value = slope * (s - self._t) + self._v
            out.append((self.start_frame + k, value))
        self.next_k = max(self.next_k, last_k + 1)
        self._t, self._v = t, v.copy()
        return out
