"""Calibration (the actor's rest face and head pose become zero) and the head / eye rotation maths.

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
from ..result import ShapeSpaceError
from ..validate import array, in_range
from .frames import implausible_channel

__all__ = ["Neutral", "calibrate", "euler_matrix", "matrix_euler", "matrix_quaternion", "rotation_power",
           "face_to_armature", "bone_local", "FACE_TO_ARMATURE"]

#: Face frame (x left, y up, z out of the face) → Blender armature axes (X left, Z up, −Y forward).
FACE_TO_ARMATURE = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
#: Largest rest weight a channel is calibrated from (a channel at rest ≥ this keeps its range).
MAX_REST_WEIGHT = 0.95


def euler_matrix(yaw_pitch_roll: ArrayLike) -> np.ndarray:
    """``(yaw, pitch, roll)`` radians → ``R = R_y(yaw) R_x(pitch) R_z(roll)``, shape (3, 3)."""
    a, b, c = (float(v) for v in yaw_pitch_roll)
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    return np.array([[ca * cc + sa * sb * sc, -ca * sc + sa * sb * cc, sa * cb],
                     [cb * sc, cb * cc, -sb],
                     [-sa * cc + ca * sb * sc, sa * sc + ca * sb * cc, ca * cb]])


def matrix_euler(R: ArrayLike) -> np.ndarray:
    """Inverse of :func:`euler_matrix`: (3, 3) rotation → ``(yaw, pitch, roll)`` radians (pitch in ±π/2)."""
    R = np.asarray(R, dtype=np.float64)
    pitch = np.arcsin(np.clip(-R[1, 2], -1.0, 1.0))
    return np.array([np.arctan2(R[0, 2], R[2, 2]), pitch, np.arctan2(R[1, 0], R[1, 1])])


def matrix_quaternion(R: ArrayLike) -> np.ndarray:
    """(3, 3) rotation → unit quaternion ``(w, x, y, z)`` with ``w ≥ 0`` (Shepperd's method)."""
    R = np.asarray(R, dtype=np.float64)
    t = np.trace(R)
    if t > 0:
        s = 2.0 * np.sqrt(1.0 + t)
        q = np.array([0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s])
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(max(1.0 + R[i, i] - R[j, j] - R[k, k], 1e-300))
        q = np.empty(4)
        q[0] = (R[k, j] - R[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (R[j, i] + R[i, j]) / s
        q[1 + k] = (R[k, i] + R[i, k]) / s
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def rotation_power(R: ArrayLike, share: float) -> np.ndarray:
    """``R^share``: the same axis, ``share`` × the angle (0 → identity, 1 → ``R``), shape (3, 3)."""
    share = in_range(share, "share", 0.0, 1.0)
    q = matrix_quaternion(R)
    angle = 2.0 * np.arctan2(np.linalg.norm(q[1:]), q[0])
    if angle < 1e-12:
        return np.eye(3)
    axis = q[1:] / np.linalg.norm(q[1:])
    theta = share * angle
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(theta) * K + (1 - np.cos(theta)) * (K @ K)


def face_to_armature(R: ArrayLike, mirror: bool = False) -> np.ndarray:
    """A face-frame rotation in Blender armature axes, ``C R Cᵀ``; ``mirror`` swaps left and right
    (a selfie-mirrored capture: yaw and roll change sign)."""
    R = np.asarray(R, dtype=np.float64)
    if mirror:
        M = np.diag([-1.0, 1.0, 1.0])
        R = M @ R @ M
    return FACE_TO_ARMATURE @ R @ FACE_TO_ARMATURE.T


def bone_local(R_armature: ArrayLike, rest: ArrayLike) -> np.ndarray:
    """The pose-bone rotation ``Bᵀ R B`` (3, 3) that turns a bone with rest orientation ``B`` (its
    ``matrix_local`` rotation, armature space) by ``R`` about its head, in armature axes."""
    B = np.asarray(rest, dtype=np.float64)
    return B.T @ np.asarray(R_armature, dtype=np.float64) @ B


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
