"""Shared input validation for every core entry point (validate first, then compute).

One dialect: each helper takes the value and the *argument name* and either
returns the checked value (a float64 array or a float) or raises
:class:`~core.result.ShapeSpaceError` with a one-line message naming the
argument, what was expected and what was given, and a code from
:class:`~core.errors.ErrorCode`.

Shape specifications use ``None`` for "any size" in a dimension, e.g.
``array(x, "neutral", shape=(None, 3))``.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, DTypeLike

from .errors import ErrorCode
from .result import ShapeSpaceError

__all__ = ["ABSURD_COORDINATE", "ABSURD_MOVE", "array", "bad_coordinate", "coordinates", "finite_scalar", "positive",
           "non_negative", "in_range", "choice", "shape_text"]


def shape_text(shape: Sequence) -> str:
    """``(None, 3)`` → ``"(n, 3)"`` (the names used in messages)."""
    letters = iter("nmkpqr")
    dims = [str(d) if d is not None else next(letters, "?") for d in shape]
    return "(" + ", ".join(dims) + ("," if len(dims) == 1 else "") + ")"


def array(x: ArrayLike, name: str, ndim: int | Sequence[int] | None = None, shape: Sequence | None = None,
          finite: bool = True, dtype: DTypeLike = np.float64) -> np.ndarray:
    """``x`` as an array, checked.

    Parameters
    ----------
    x : array_like
    name : str
        Argument name used in the message.
    ndim : int or sequence of int, optional
        Allowed numbers of dimensions.
    shape : sequence of (int or None), optional
        Required shape; ``None`` entries match any size.  Implies ``ndim``.
    finite : bool
        Refuse NaN and infinities (code ``non_finite``).
    dtype : numpy dtype
        Result dtype (float64 by default).

    Returns
    -------
    ndarray
    """
    try:
        arr = np.asarray(x, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise ShapeSpaceError(f"{name} must be numeric, got {type(x).__name__} ({exc})", ErrorCode.DTYPE) from None
    if shape is not None:
        ok = arr.ndim == len(shape) and all(s is None or s == a for s, a in zip(shape, arr.shape))
        if not ok:
            raise ShapeSpaceError(f"{name} must have shape {shape_text(shape)}, got {arr.shape}", ErrorCode.SHAPE)
    elif ndim is not None:
        allowed = (ndim,) if isinstance(ndim, int) else tuple(ndim)
        if arr.ndim not in allowed:
            want = " or ".join(str(d) for d in allowed)
            raise ShapeSpaceError(f"{name} must have {want} dimensions, got shape {arr.shape}", ErrorCode.SHAPE)
    if finite and arr.size and not np.isfinite(arr).all():
        bad = np.argwhere(~np.isfinite(arr))[0]
        where = tuple(int(i) for i in bad)
        raise ShapeSpaceError(f"{name} contains NaN or infinite values (first at index {where})",
                              ErrorCode.NON_FINITE)
    return arr


#: Blender units beyond which a coordinate is absurd for a face (a million: no head, whatever the unit scale).
ABSURD_COORDINATE = 1e6
#: Head sizes (the basis's bounding-box diagonal) beyond which a shape key's move of a vertex is absurd.
ABSURD_MOVE = 100.0


def bad_coordinate(co: np.ndarray, limit: float = math.inf) -> tuple | None:
    """The first coordinate of ``co`` (p, 3) that is NaN, infinite or larger than ``limit`` in magnitude, as
    ``(vertex, axis, value)``; None when every one is sound."""
    bad = ~np.isfinite(co) | (np.abs(co) > limit)
    if not bad.any():
        return None
    v, axis = (int(i) for i in np.argwhere(bad)[0])
    return v, axis, float(co[v, axis])


def coordinates(co: np.ndarray, what: str, limit: float = math.inf, fix: str = "fix or delete the key") -> np.ndarray:
    """``co`` (p, 3) when every coordinate is finite (and at most ``limit`` in magnitude); otherwise one line
    naming ``what`` (e.g. ``shape key 'K1' of 'Face'``), the vertex and the axis (code ``non_finite``)."""
    found = bad_coordinate(co, limit)
    if found is not None:
        v, axis, value = found
        kind = "a non-finite" if not math.isfinite(value) else "an absurd"
        raise ShapeSpaceError(f"{what} has {kind} coordinate ({'xyz'[axis]} = {value:g}) at vertex {v}; {fix}",
                              ErrorCode.NON_FINITE)
    return co


def finite_scalar(x: Any, name: str) -> float:
    """``x`` as a finite float (code ``non_finite`` for NaN/inf, ``not_number`` otherwise)."""
    try:
        value = float(x)
    except (TypeError, ValueError):
        raise ShapeSpaceError(f"{name} must be a number, got {x!r}", ErrorCode.NOT_NUMBER) from None
    if not math.isfinite(value):
        raise ShapeSpaceError(f"{name} must be finite, got {value}", ErrorCode.NON_FINITE)
    return value


def positive(x: Any, name: str) -> float:
    """``x`` as a finite float > 0 (code ``range``)."""
    value = finite_scalar(x, name)
    if value <= 0:
        raise ShapeSpaceError(f"{name} must be positive, got {value}", ErrorCode.RANGE)
    return value


def non_negative(x: Any, name: str) -> float:
    """``x`` as a finite float ≥ 0 (code ``range``)."""
    value = finite_scalar(x, name)
    if value < 0:
        raise ShapeSpaceError(f"{name} must be ≥ 0, got {value}", ErrorCode.RANGE)
    return value


def in_range(x: Any, name: str, lo: float, hi: float) -> float:
    """``x`` as a finite float in ``[lo, hi]`` (code ``range``)."""
    value = finite_scalar(x, name)
    if not lo <= value <= hi:
        raise ShapeSpaceError(f"{name} must be in [{lo}, {hi}], got {value}", ErrorCode.RANGE)
    return value


def choice(x: Any, name: str, options: Sequence[str], code: ErrorCode = ErrorCode.METHOD) -> str:
    """``x`` if it is one of ``options`` (message lists them)."""
    if x not in options:
        raise ShapeSpaceError(f"{name} must be one of {', '.join(map(repr, options))}, got {x!r}", code)
    return x
