"""The One-Euro filter (Casiez, Roussel & Vogel, CHI 2012), vectorised over channels.

A first-order low-pass whose cutoff rises with the signal's speed: slow
motion (an actor holding still) is smoothed hard, which removes jitter, fast
motion passes with little lag.  Per channel, for samples ``x_i`` at times
``t_i`` (``Δ = t_i − t_{i−1}``)::

    α(f_c) = 1 / (1 + τ/Δ),  τ = 1 / (2π f_c)
    d̂_i  = d̂_{i−1} + α(f_d) ((x_i − x̂_{i−1})/Δ − d̂_{i−1})
    f_c  = f_min + β |d̂_i|
    x̂_i  = x̂_{i−1} + α(f_c) (x_i − x̂_{i−1})

``f_min`` (Hz) sets the smoothing at rest, ``β`` how fast the cutoff follows
speed, ``f_d`` the cutoff of the speed estimate.
"""
from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from ..validate import array, non_negative, positive

__all__ = ["OneEuroFilter"]


class OneEuroFilter:
    """One-Euro filter state for a vector of channels (weights, angles, …).

    Parameters
    ----------
    min_cutoff : float
        ``f_min`` in Hz, > 0 (lower = smoother at rest).
    beta : float
        Speed coefficient, ≥ 0 (higher = less lag on fast motion).
    d_cutoff : float
        Cutoff of the speed estimate in Hz, > 0.
    """

    def __init__(self, min_cutoff: float = 1.0, beta: float = 0.0, d_cutoff: float = 1.0) -> None:
        self.min_cutoff = positive(min_cutoff, "min_cutoff")
        self.beta = non_negative(beta, "beta")
        self.d_cutoff = positive(d_cutoff, "d_cutoff")
        self.reset()

    def reset(self) -> None:
        """Forget the history (the next sample passes unchanged)."""
        self._x = None
        self._dx = None
        self._t = None

    @staticmethod
    def _alpha(cutoff: np.ndarray | float, dt: float) -> np.ndarray | float:
        tau = 1.0 / (2.0 * math.pi * cutoff)
        return 1.0 / (1.0 + tau / dt)

    def __call__(self, x: ArrayLike, t: float) -> np.ndarray:
        """Filter sample ``x`` (n,) taken at time ``t`` (seconds); returns the smoothed sample (n,).

        A sample not later than the previous one (a repeated time) returns the last output unchanged.
        """
        x = array(x, "x", ndim=1)
        if self._x is None or self._x.shape != x.shape:
            self._x, self._dx, self._t = x.copy(), np.zeros_like(x), float(t)
            return x.copy()
        dt = float(t) - self._t
        if not dt > 1e-9:
            return self._x.copy()
        dx = (x - self._x) / dt
        self._dx = self._dx + self._alpha(self.d_cutoff, dt) * (dx - self._dx)
        cutoff = self.min_cutoff + self.beta * np.abs(self._dx)
        self._x = self._x + self._alpha(cutoff, dt) * (x - self._x)
        self._t = float(t)
        return self._x.copy()
