"""Pose space: turning a rig's pose into a feature vector (thesis 7.3, 8.1).

Each :class:`PoseReader` maps one control to a few numbers whose Euclidean
distance is a sensible pose distance:

- ``rotation`` — a bone's local rotation as ``(R − I)/√2`` (9 numbers): the
  distance is ``2|sin(θ/2)|`` for a relative rotation by θ, so q and −q are
  the same pose and small angles read as radians;
- ``swing`` — where the bone's own axis (Y) points, ``R·ŷ − ŷ`` (3 numbers):
  a forearm roll does not move it;
- ``twist`` — the roll about the bone's axis, ``(cos τ − 1, sin τ)`` (2
  numbers): swinging the bone does not move it;
- ``location`` (3), ``property`` (1, e.g. an "exertion" adjective, 7.3.2) and
  ``shape_key`` (1, weighted pose-space editing in blendshape space, 7.3.4).

Every reader has a ``scale`` (per-dimension weighting of the pose space).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .. import validate
from ..errors import ErrorCode
from ..result import ShapeSpaceError

__all__ = ["PoseReader", "READER_DIMS", "quaternion_distance", "quaternion_to_matrix", "swing_twist",
           "reader_features", "pose_features", "feature_groups"]

READER_DIMS = {"rotation": 9, "swing": 3, "twist": 2, "location": 3, "property": 1, "shape_key": 1}


@dataclass(frozen=True)
class PoseReader:
    """One pose-space control.

    Attributes
    ----------
    kind : str
        ``rotation``, ``swing``, ``twist``, ``location``, ``property`` or ``shape_key``.
    source : str
        Bone name, custom-property path or shape-key name.
    scale : float
        Multiplies this reader's features (per-dimension weighting).
    """

    kind: str
    source: str
    scale: float = 1.0

    def __post_init__(self):
        if self.kind not in READER_DIMS:
            raise ShapeSpaceError(f"unknown pose reader {self.kind!r}; choose from {', '.join(READER_DIMS)}",
                                  ErrorCode.READER)
        if not (np.isfinite(self.scale) and self.scale > 0):
            raise ShapeSpaceError(f"reader scale of {self.kind} {self.source!r} must be a positive number, got "
                                  f"{self.scale}", ErrorCode.RANGE)

    @property
    def dims(self) -> int:
        """Number of features this reader contributes (:data:`READER_DIMS`)."""
        return READER_DIMS[self.kind]

    @property
    def is_bone(self) -> bool:
        """True for the readers of a bone's transform (rotation, swing, twist, location)."""
        return self.kind in ("rotation", "swing", "twist", "location")


def _unit_quats(q, name: str = "quaternions") -> np.ndarray:
    """Quaternions (..., 4) normalised; zero or non-finite ones are refused (code ``non_finite``)."""
    q = validate.array(q, name, finite=False)
    if q.ndim < 1 or q.shape[-1] != 4:
        raise ShapeSpaceError(f"{name} must have last dimension 4 (w, x, y, z), got {q.shape}",
                              ErrorCode.SHAPE)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(n < 1e-12) or not np.isfinite(q).all():
        raise ShapeSpaceError(f"{name} must be finite and non-zero", ErrorCode.NON_FINITE)
    return q / n


def quaternion_distance(q: ArrayLike, p: ArrayLike) -> np.ndarray:
    """Rotation angle between unit quaternions, treating q and −q as the same: ``2·acos|q·p|``.

    Parameters
    ----------
    q, p : array_like, shape (..., 4)
        Quaternions (w, x, y, z), normalised here; broadcast against each other.

    Returns
    -------
    ndarray, shape (...)
        Angles in [0, π].
    """
    dot = np.abs(np.sum(_unit_quats(q) * _unit_quats(p), axis=-1))
    return 2.0 * np.arccos(np.clip(dot, 0.0, 1.0))


def quaternion_to_matrix(q: ArrayLike) -> np.ndarray:
    """Rotation matrices of quaternions.

    Parameters
    ----------
    q : array_like, shape (..., 4)
        (w, x, y, z), normalised here.

    Returns
    -------
    ndarray, shape (..., 3, 3)
    """
    w, x, y, z = np.moveaxis(_unit_quats(q), -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def swing_twist(q: ArrayLike, axis: ArrayLike = (0.0, 1.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """Split rotations into swing · twist about ``axis`` (a bone's Y by default; thesis 7.3).

    Parameters
    ----------
    q : array_like, shape (..., 4)
        Quaternions (w, x, y, z).
    axis : array_like, shape (3,)
        Twist axis (normalised here).

    Returns
    -------
    swing : ndarray (..., 4)
        The rotation taking ``axis`` to where ``q`` takes it, with no roll.
    twist : ndarray (...,)
        The roll angle about ``axis`` in [−π, π), the same for q and −q.
    """
    q = _unit_quats(q)
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    proj = np.sum(q[..., 1:] * a, axis=-1)
    tw = np.concatenate([q[..., :1], proj[..., None] * a], axis=-1)
    n = np.linalg.norm(tw, axis=-1, keepdims=True)
    tw = np.where(n > 1e-12, tw / np.where(n > 1e-12, n, 1.0), np.array([1.0, 0, 0, 0]))
    angle = 2.0 * np.arctan2(np.sum(tw[..., 1:] * a, axis=-1), tw[..., 0])
    angle = (angle + np.pi) % (2 * np.pi) - np.pi
    # swing = q · twist⁻¹
    tw_inv = tw * np.array([1.0, -1.0, -1.0, -1.0])
    w1, x1, y1, z1 = np.moveaxis(q, -1, 0)
    w2, x2, y2, z2 = np.moveaxis(tw_inv, -1, 0)
    swing = np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
                      w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                      w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                      w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], -1)
    return swing, angle


def reader_features(reader: PoseReader, value: ArrayLike) -> np.ndarray:
    """Features of one reader from its raw value(s) (thesis 7.3, 8.1).

    Parameters
    ----------
    reader : PoseReader
    value : array_like
        A quaternion (..., 4) for rotation/swing/twist, a vector (..., 3)
        for location and a scalar (...) for property/shape_key.

    Returns
    -------
    ndarray, shape (..., reader.dims)
        Already multiplied by ``reader.scale``.
    """
    kind = reader.kind
    if kind in ("rotation", "swing", "twist"):
        q = _unit_quats(value, f"the rotation of {kind} reader {reader.source!r}")
        if kind == "rotation":
            R = quaternion_to_matrix(q)
            f = (R - np.eye(3)).reshape(q.shape[:-1] + (9,)) / np.sqrt(2.0)
        elif kind == "swing":
            f = quaternion_to_matrix(q)[..., :, 1] - np.array([0.0, 1.0, 0.0])
        else:
            _, tau = swing_twist(q)
            f = np.stack([np.cos(tau) - 1.0, np.sin(tau)], axis=-1)
    elif kind == "location":
        f = np.asarray(value, dtype=np.float64)
        if f.shape[-1] != 3:
            raise ShapeSpaceError(f"a location reader needs 3 values, got shape {f.shape}", ErrorCode.SHAPE)
    else:
        f = np.asarray(value, dtype=np.float64)[..., None]
    if not np.isfinite(f).all():
        raise ShapeSpaceError(f"pose value of {reader.kind} {reader.source!r} is not finite", ErrorCode.NON_FINITE)
    return f * reader.scale


def pose_features(readers: Sequence[PoseReader], values: Sequence[Any]) -> np.ndarray:
    """The pose-space location: concatenated features of all readers (thesis 8.1).

    Parameters
    ----------
    readers : sequence of PoseReader
    values : sequence
        One raw value per reader (see :func:`reader_features`).

    Returns
    -------
    ndarray, shape (..., Σ dims)
    """
    if len(readers) != len(values):
        raise ShapeSpaceError(f"{len(values)} values for {len(readers)} pose readers", ErrorCode.SHAPE)
    if not readers:
        raise ShapeSpaceError("a pose space needs at least one reader", ErrorCode.NO_READERS)
    return np.concatenate([reader_features(r, v) for r, v in zip(readers, values)], axis=-1)


def feature_groups(readers: Sequence[PoseReader]) -> dict[str, np.ndarray]:
    """Feature columns per source (bone, property, key): ``{source: index array}`` (for weighted PSD)."""
    out, start = {}, 0
    for r in readers:
        cols = np.arange(start, start + r.dims)
        out[r.source] = np.concatenate([out[r.source], cols]) if r.source in out else cols
        start += r.dims
    return out
