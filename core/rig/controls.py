"""The controls of any face rig: which animatable channels a solve may move, their bounds and natural scales.

A rig that is not a linear shape-key model (bones, drivers, hybrids; thesis 3.3.4) is driven by *channels*:
one axis of a pose bone's rotation in the bone's own rotation mode, one axis of its location or scale, a custom
property, or a shape-key slider.  A :class:`ControlSet` is an ordered tuple of :class:`Channel` s; a control
vector ``c`` (n,) holds one value per channel in that order.

Rotation channels of a bone whose rotation mode is an Euler order are the Euler angles themselves (radians).
Bones in ``QUATERNION`` or ``AXIS_ANGLE`` mode are controlled through the rotation vector (axis × angle, the
logarithm of the rotation; :func:`rotation_vector_from_quaternion` and :func:`quaternion_from_rotation_vector`):
three smooth, unconstrained coordinates, zero at the rest pose, whose x/y/z lock flags are the bone's.

Each channel carries bounds ``[lo, hi]`` (infinite when the rig sets none), a ``locked`` flag (a channel the
rig forbids to move: the solve holds it where it is) and a *natural scale* ``scale`` — how far the surface
moves per unit of the channel (the largest vertex displacement per unit, in the surface's length unit).  The
natural scale makes the regularisation and the finite-difference steps comparable across radians, metres,
slider units and property units.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ErrorCode
from ..result import ShapeSpaceError

__all__ = ["Channel", "ChannelKind", "ControlSet", "quaternion_from_rotation_vector",
           "rotation_vector_from_quaternion"]


class ChannelKind(str, enum.Enum):
    """What a channel drives (value = the stable name used in reports)."""

    ROTATION = "rotation"
    LOCATION = "location"
    SCALE = "scale"
    PROPERTY = "property"
    SHAPE_KEY = "shape_key"


#: Default finite-difference step per unit of each kind when the channel's bounds do not give one
#: (radians, length units of the rig, scale factor, property units, slider units).
DEFAULT_STEP = {ChannelKind.ROTATION: 1e-3, ChannelKind.LOCATION: 1e-3, ChannelKind.SCALE: 1e-3,
                ChannelKind.PROPERTY: 1e-3, ChannelKind.SHAPE_KEY: 1e-3}


@dataclass(frozen=True)
class Channel:
    """One animatable channel of a rig.

    Attributes
    ----------
    name : str
        Label that names the channel in every message, e.g. ``'jaw rotation X'``, ``'key jawOpen'``.
    kind : ChannelKind
    owner : str
        Name of the object that owns the channel (the armature or the mesh object).
    path : str
        Data path from the owner, without the index (``'pose.bones["jaw"].rotation_euler'``,
        ``'data.shape_keys.key_blocks["jawOpen"].value'``, ``'pose.bones["ctl"]["smile"]'``).
    index : int
        Array index in ``path`` (the axis), ``-1`` for a scalar.
    lo, hi : float
        Bounds (``-inf``/``inf`` when the rig sets none).
    locked : bool
        The rig forbids moving this channel (bone lock flags).
    rotation_mode : str
        For rotation channels, the bone's rotation mode (``'XYZ'`` … or ``'QUATERNION'``/``'AXIS_ANGLE'``, then
        the channel is a rotation-vector component); empty otherwise.
    scale : float
        Natural scale: surface displacement per unit of the channel (``1.0`` until measured).
    """

    name: str
    kind: ChannelKind
    owner: str
    path: str
    index: int = -1
    lo: float = -np.inf
    hi: float = np.inf
    locked: bool = False
    rotation_mode: str = ""
    scale: float = 1.0

    def __post_init__(self):
        object.__setattr__(self, "kind", ChannelKind(self.kind))
        lo, hi = float(self.lo), float(self.hi)
        if np.isnan(lo) or np.isnan(hi) or lo > hi:
            raise ShapeSpaceError(f"channel {self.name!r}: bounds [{lo}, {hi}] are not an interval",
                                  ErrorCode.RANGE)
        if not (np.isfinite(self.scale) and self.scale > 0):
            raise ShapeSpaceError(f"channel {self.name!r}: natural scale {self.scale} is not a positive number",
                                  ErrorCode.RANGE)

    @property
    def key(self) -> tuple:
        """Identity of the channel (owner, path, index): two channels with the same key are the same channel."""
        return (self.owner, self.path, self.index)

    def default_step(self) -> float:
        """A finite-difference step in the channel's unit: 1e-3 of its range when bounded, else per kind."""
        if np.isfinite(self.lo) and np.isfinite(self.hi) and self.hi > self.lo:
            return 1e-3 * (self.hi - self.lo)
        return DEFAULT_STEP[self.kind]


@dataclass(frozen=True)
class ControlSet:
    """An ordered set of channels (the unknowns of a rig solve).

    Attributes
    ----------
    channels : tuple of Channel
        Distinct channels (by :attr:`Channel.key`), at least one.
    """

    channels: tuple

    def __post_init__(self):
        chans = tuple(self.channels)
        if not chans:
            raise ShapeSpaceError("the control set has no channels", ErrorCode.NO_CHANNELS)
        seen = {}
        for ch in chans:
            if not isinstance(ch, Channel):
                raise ShapeSpaceError(f"control set entry {ch!r} is not a Channel", ErrorCode.TYPE)
            if ch.key in seen:
                raise ShapeSpaceError(f"channel {ch.name!r} is listed twice (also as {seen[ch.key]!r})",
                                      ErrorCode.DUPLICATE_NAME)
            seen[ch.key] = ch.name
        object.__setattr__(self, "channels", chans)

    def __len__(self) -> int:
        return len(self.channels)

    @property
    def names(self) -> list:
        return [ch.name for ch in self.channels]

    @property
    def lo(self) -> np.ndarray:
        """Lower bounds (n,) float64."""
        return np.array([ch.lo for ch in self.channels], dtype=np.float64)

    @property
    def hi(self) -> np.ndarray:
        """Upper bounds (n,) float64."""
        return np.array([ch.hi for ch in self.channels], dtype=np.float64)

    @property
    def locked(self) -> np.ndarray:
        """Lock flags (n,) bool."""
        return np.array([ch.locked for ch in self.channels], dtype=bool)

    @property
    def scale(self) -> np.ndarray:
        """Natural scales (n,) float64."""
        return np.array([ch.scale for ch in self.channels], dtype=np.float64)

    def steps(self) -> np.ndarray:
        """Finite-difference steps (n,) float64 (:meth:`Channel.default_step`)."""
        return np.array([ch.default_step() for ch in self.channels], dtype=np.float64)

    def solve_bounds(self, current: ArrayLike) -> tuple:
        """Bounds for a solve from ``current`` (n,): locked channels held at their current value.

        Returns
        -------
        (ndarray (n,), ndarray (n,))
            ``lo``, ``hi``; a current value outside its bounds widens them to include it (the solve never
            has to jump to become feasible), and is reported by :meth:`out_of_bounds`.
        """
        c = self.vector(current)
        lo, hi = np.minimum(self.lo, c), np.maximum(self.hi, c)
        locked = self.locked
        lo[locked] = c[locked]
        hi[locked] = c[locked]
        return lo, hi

    def out_of_bounds(self, current: ArrayLike) -> list:
        """Names of the channels whose value in ``current`` (n,) lies outside their bounds."""
        c = self.vector(current)
        bad = (c < self.lo) | (c > self.hi)
        return [self.channels[i].name for i in np.flatnonzero(bad)]

    def vector(self, values: ArrayLike, name: str = "controls") -> np.ndarray:
        """``values`` as a finite float64 control vector (n,), or :class:`ShapeSpaceError` naming the culprit."""
        c = np.array(values, dtype=np.float64).reshape(-1)
        if c.shape != (len(self),):
            raise ShapeSpaceError(f"{name}: expected {len(self)} values (one per channel), got {c.size}",
                                  ErrorCode.SHAPE)
        bad = np.flatnonzero(~np.isfinite(c))
        if bad.size:
            raise ShapeSpaceError(f"{name}: channel {self.channels[bad[0]].name!r} is {c[bad[0]]}",
                                  ErrorCode.NON_FINITE)
        return c

    def with_scales(self, scales: ArrayLike) -> ControlSet:
        """A copy with the natural scales replaced by ``scales`` (n,) (each positive and finite)."""
        s = self.vector(scales, "scales")
        return ControlSet(tuple(replace(ch, scale=float(v)) for ch, v in zip(self.channels, s)))

    def index(self, name: str) -> int:
        """Position of the channel called ``name``."""
        for i, ch in enumerate(self.channels):
            if ch.name == name:
                return i
        raise ShapeSpaceError(f"no channel {name!r} in the control set", ErrorCode.MISSING_CHANNEL)


def rotation_vector_from_quaternion(q: ArrayLike) -> np.ndarray:
    """Rotation vector (axis × angle, radians) of a unit quaternion ``(w, x, y, z)``, angle in [0, π].

    Parameters
    ----------
    q : array_like (4,)
        Need not be normalised; must not be zero.

    Returns
    -------
    ndarray (3,)
    """
    q = np.asarray(q, dtype=np.float64).reshape(4)
    norm = np.linalg.norm(q)
    if not np.isfinite(norm) or norm == 0.0:
        raise ShapeSpaceError(f"quaternion {q.tolist()} is not a rotation", ErrorCode.NON_FINITE)
    q = q / norm
    if q[0] < 0.0:
        q = -q
    s = np.linalg.norm(q[1:])
    if s < 1e-12:
        return 2.0 * q[1:]
    return (2.0 * np.arctan2(s, q[0]) / s) * q[1:]


def quaternion_from_rotation_vector(v: ArrayLike) -> np.ndarray:
    """Unit quaternion ``(w, x, y, z)`` of a rotation vector (axis × angle, radians) (3,) → (4,)."""
    v = np.asarray(v, dtype=np.float64).reshape(3)
    angle = np.linalg.norm(v)
    half = 0.5 * angle
    k = 0.5 * np.sinc(half / np.pi)          # sin(half)/angle, smooth at 0
    return np.concatenate(([np.cos(half)], k * v))
