"""A live stream resampled onto scene frames as it arrives: what a recorded take keys.

The offline retarget resamples a capture onto the scene's frames by linear
interpolation in time (:func:`core.retarget.resample`): with the capture's
times ``t`` shifted to start at 0, scene frame ``start + k`` takes the capture
at ``t = k / rate``, for every ``k`` up to ``⌊t_last · rate + 10⁻⁹⌋``.
:class:`SceneResampler` does the same incrementally: each new sample emits the
scene frames that now lie inside the stream, interpolated between the two
samples around them — so a recorded take is the offline resample of the same
frames, sample for sample.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from ..validate import finite_scalar, positive

__all__ = ["SceneResampler"]


class SceneResampler:
    """Turn ``(time, vector)`` samples into ``(scene frame, vector)`` samples at the scene rate.

    Parameters
    ----------
    rate : float
        Scene frames per second (``fps / fps_base``).
    start_frame : float
        The scene frame of the first sample.
    """

    def __init__(self, rate: float, start_frame: float = 1.0) -> None:
        self.rate = positive(rate, "rate")
        self.start_frame = finite_scalar(start_frame, "start_frame")
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

    def push(self, time: float, vector: ArrayLike) -> list:
        """Add a sample; returns ``[(scene frame, vector (n,))]`` for the scene frames it completes.

        Samples must come in increasing time; a sample not later than the previous one is ignored.
        """
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
