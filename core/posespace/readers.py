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

from dataclasses import dataclass

import numpy as np

from ..result import ShapeSpaceError

__all__ = ["PoseReader", "READER_DIMS", "quaternion_distance", "quaternion_to_matrix", "swing_twist",
           "reader_features", "pose_features", "feature_groups", "mirror_name", "mirror_features", "mirror_pose"]

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
                                  "reader")
        if not self.scale > 0:
            raise ShapeSpaceError(f"reader scale must be positive, got {self.scale}", "range")

    @property
    def dims(self) -> int:
        return READER_DIMS[self.kind]

    @property
    def is_bone(self) -> bool:
        return self.kind in ("rotation", "swing", "twist", "location")


def _unit_quats(q):
    q = np.asarray(q, dtype=np.float64)
    if q.shape[-1] != 4:
        raise ShapeSpaceError(f"quaternions must have last dimension 4 (w, x, y, z), got {q.shape}", "shape")
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(n < 1e-12) or not np.isfinite(q).all():
        raise ShapeSpaceError("quaternions must be finite and non-zero", "non_finite")
    return q / n


def quaternion_distance(q, p) -> np.ndarray:
    """Rotation angle between unit quaternions (w, x, y, z), treating q and −q as the same: ``2·acos|q·p|``."""
    dot = np.abs(np.sum(_unit_quats(q) * _unit_quats(p), axis=-1))
    return 2.0 * np.arccos(np.clip(dot, 0.0, 1.0))


def quaternion_to_matrix(q) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of quaternions (..., 4) in (w, x, y, z) order."""
    w, x, y, z = np.moveaxis(_unit_quats(q), -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def swing_twist(q, axis=(0.0, 1.0, 0.0)):
    """Split rotations into swing · twist about ``axis`` (a bone's Y by default).

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


def reader_features(reader: PoseReader, value) -> np.ndarray:
    """Features of one reader from its raw value(s), shape (..., reader.dims).

    ``value`` is a quaternion (..., 4) for rotation/swing/twist, a vector
    (..., 3) for location and a scalar (...) for property/shape_key.
    """
    kind = reader.kind
    if kind in ("rotation", "swing", "twist"):
        q = _unit_quats(value)
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
            raise ShapeSpaceError(f"a location reader needs 3 values, got shape {f.shape}", "shape")
    else:
        f = np.asarray(value, dtype=np.float64)[..., None]
    if not np.isfinite(f).all():
        raise ShapeSpaceError(f"pose value of {reader.kind} {reader.source!r} is not finite", "non_finite")
    return f * reader.scale


def pose_features(readers, values) -> np.ndarray:
    """Concatenated features of all readers, shape (..., Σ dims).

    Parameters
    ----------
    readers : sequence of PoseReader
    values : sequence
        One raw value per reader (see :func:`reader_features`).
    """
    if len(readers) != len(values):
        raise ShapeSpaceError(f"{len(values)} values for {len(readers)} pose readers", "shape")
    if not readers:
        raise ShapeSpaceError("a pose space needs at least one reader", "no_readers")
    return np.concatenate([reader_features(r, v) for r, v in zip(readers, values)], axis=-1)


def feature_groups(readers) -> dict:
    """Feature columns per source (bone, property, key): ``{source: index array}`` (for weighted PSD)."""
    out, start = {}, 0
    for r in readers:
        cols = np.arange(start, start + r.dims)
        out[r.source] = np.concatenate([out[r.source], cols]) if r.source in out else cols
        start += r.dims
    return out


_SIDES = (("Left", "Right"), ("left", "right"), (".L", ".R"), ("_L", "_R"), (".l", ".r"), ("_l", "_r"),
          ("L_", "R_"), ("l_", "r_"))


def mirror_name(name: str) -> str:
    """The left↔right counterpart of a bone/key name (``hand.L`` ↔ ``hand.R``, ``LeftArm`` ↔ ``RightArm``,
    ``hand.L.001`` ↔ ``hand.R.001``)."""
    import re
    m = re.match(r"^(.*?)(\.\d{3})$", name)
    if m:
        return mirror_name(m.group(1)) + m.group(2)
    for a, b in _SIDES:
        for x, y in ((a, b), (b, a)):
            if name.endswith(x):
                return name[: -len(x)] + y
            if name.startswith(x):
                return y + name[len(x):]
    for x, y in (("Left", "Right"), ("Right", "Left")):
        if x in name:
            return name.replace(x, y, 1)
    return name


def mirror_features(reader: PoseReader, feats) -> np.ndarray:
    """Features of the mirrored pose (Blender's flipped pose: local quaternion (w, x, −y, −z), location −x)."""
    f = np.asarray(feats, dtype=np.float64) / reader.scale
    D = np.diag([1.0, -1.0, -1.0])
    if reader.kind == "rotation":
        out = (D @ f.reshape(3, 3) @ D).ravel()
    elif reader.kind == "swing":
        out = -(D @ f)
    elif reader.kind == "twist":
        out = np.array([f[0], -f[1]])
    elif reader.kind == "location":
        out = f * np.array([-1.0, 1.0, 1.0])
    else:
        out = f
    return out * reader.scale


def mirror_pose(readers, pose):
    """Mirror a pose vector: each reader's features flipped and moved to its counterpart reader.

    Raises
    ------
    ShapeSpaceError
        When a reader's counterpart is not in the pose space.
    """
    readers = list(readers)
    pose = np.asarray(pose, dtype=np.float64)
    index = {(r.kind, r.source): i for i, r in enumerate(readers)}
    starts = np.concatenate([[0], np.cumsum([r.dims for r in readers])])
    out = np.empty_like(pose)
    for i, r in enumerate(readers):
        j = index.get((r.kind, mirror_name(r.source)))
        if j is None:
            raise ShapeSpaceError(f"the pose space has no {r.kind} reader for {mirror_name(r.source)!r} "
                                  f"(the mirror of {r.source!r})", "no_mirror")
        out[starts[j]:starts[j + 1]] = mirror_features(r, pose[starts[i]:starts[i + 1]])
    return out
