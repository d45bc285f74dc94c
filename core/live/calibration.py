"""Calibration (the actor's rest face and head pose become zero); the head / eye rotation maths are
:mod:`core.headpose`'s (shared with recorded takes), re-exported here.

Rotations arrive as ``(yaw, pitch, roll)`` in the face frame (x: the face's
left, y: up, z: out of the face), ``R = R_y(yaw) R_x(pitch) R_z(roll)``.

- Calibration: with the rest frame's weights ``n`` and rotations ``R₀``, a
  frame becomes ``w' = max((w − n) / (1 − n), 0)`` (rest → 0, full → 1) and
  ``R' = R₀ᵀ R`` (the rest pose → identity).
- Bones: the face frame maps onto Blender's armature axes (X the character's
  left, Z up, −Y forward: ``C`` below); a bone whose rest orientation in
  armature space is ``B`` takes the local rotation ``L = Bᵀ (C R Cᵀ) B``.
  The head / neck split gives the neck ``R^s`` and the head ``R^(1−s)`` (powers
  of one rotation commute, so the chain composes to exactly ``R``).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ErrorCode
from ..headpose import (
    FACE_TO_ARMATURE,
    bone_local,
    euler_matrix,
    face_to_armature,
    matrix_euler,
    matrix_quaternion,
    rotation_power,
)
from ..result import ShapeSpaceError
from ..validate import array
from .frames import implausible_channel

__all__ = ["CalibratedInput", "Neutral",
           "calibrate", "euler_matrix", "matrix_euler", "matrix_quaternion", "rotation_power",
           "face_to_armature", "bone_local", "FACE_TO_ARMATURE"]

#: Largest rest weight a channel is calibrated from (a channel at rest ≥ this keeps its range).
MAX_REST_WEIGHT = 0.95


@dataclass
class Neutral:
    """The actor's rest frame: blendshape weights (n,) and head / eye rotations (3, 3) each."""

    weights: np.ndarray
    head: np.ndarray
    eye_left: np.ndarray
    eye_right: np.ndarray

    @classmethod
    def from_vector(cls, vector: ArrayLike, n_weights: int, names: Sequence[str] | None = None) -> "Neutral":
        """From a frame vector ``[weights, head ypr, left eye ypr, right eye ypr]`` (n + 9,).

        ``names`` (n,) name the weights in messages.  A rest frame beyond the live plausibility limits
        (:func:`~.frames.implausible_channel`) is refused (``range``): every later frame would read from it.
        """
        v = array(vector, "rest frame", shape=(n_weights + 9,))
        why = implausible_channel(names or [f"channel {i}" for i in range(n_weights)], v)
        if why:
            raise ShapeSpaceError(f"the rest face cannot be calibrated from this frame: {why}", ErrorCode.RANGE)
        return cls(v[:n_weights].copy(), euler_matrix(v[n_weights:n_weights + 3]),
                   euler_matrix(v[n_weights + 3:n_weights + 6]), euler_matrix(v[n_weights + 6:]))


def calibrate(vector: ArrayLike, neutral: Neutral | None) -> np.ndarray:
    """A frame vector ``[weights, head, eye_left, eye_right]`` (n + 9,) relative to the actor's rest.

    ``w' = max((w − n) / (1 − n), 0)`` for channels resting below :data:`MAX_REST_WEIGHT` (others are
    left as they are), rotations ``R' = R₀ᵀ R`` back to ``(yaw, pitch, roll)``.  ``neutral=None``
    returns the vector unchanged.
    """
    v = np.array(vector, dtype=np.float64)
    if neutral is None:
        return v
    n = neutral.weights.size
    rest = neutral.weights
    use = rest < MAX_REST_WEIGHT
    w = v[:n]
    w[use] = np.maximum((w[use] - rest[use]) / (1.0 - rest[use]), 0.0)
    for k, R0 in enumerate((neutral.head, neutral.eye_left, neutral.eye_right)):
        sl = slice(n + 3 * k, n + 3 * k + 3)
        v[sl] = matrix_euler(R0.T @ euler_matrix(v[sl]))
    return v


class CalibratedInput:
    """What every live pipeline does to a raw frame before solving: calibrate it against the actor's rest frame,
    then smooth it.  A mixin: the pipeline carries ``n_source`` (weights per frame), ``neutral``
    (:class:`Neutral` or None) and ``smoothing`` (a :class:`core.live.OneEuroFilter` or None)."""

    n_source: int
    neutral: Neutral | None
    smoothing: object

    def process(self, vector: np.ndarray, time: float) -> np.ndarray:
        """A raw frame vector (n + 9,) calibrated and smoothed."""
        v = calibrate(vector, self.neutral)
        return self.smoothing(v, time) if self.smoothing is not None else v

    def calibrate_to(self, raw: np.ndarray) -> None:
        """Make ``raw`` (an uncalibrated frame vector) the rest frame; the smoothing starts afresh."""
        self.neutral = Neutral.from_vector(raw, self.n_source)
        if self.smoothing is not None:
            self.smoothing.reset()
