"""In-betweens of two expressions: linear, or along the prior's probability shell (thesis 6.5).

J.P. Lewis, *Learning from the Artist*, 2016, section 6.5: a plain lerp between two
typical faces cuts through the improbable interior of the face-space Gaussian toward
the (atypical) mean face, so an expression loses strength half-way.  Shell
interpolation slerps the whitened direction and lerps the radius instead, staying on
the hyperellipsoid of typical faces.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .. import validate
from ..errors import ErrorCode
from ..result import ShapeSpaceError
from .prior import FaceGaussian

__all__ = ["linear_interpolate", "shell_interpolate", "INTERPOLATIONS", "interpolate", "inbetween_times",
           "fill_range"]

#: In-between modes of :func:`interpolate`.
INTERPOLATIONS = ("SHELL", "LINEAR")


def _times(t) -> np.ndarray:
    t = np.atleast_1d(validate.array(t, "t"))
    if t.ndim != 1:
        raise ShapeSpaceError(f"t must be a 1-D array of values in [0, 1], got shape {t.shape}", ErrorCode.SHAPE)
    if t.size and (t.min() < 0 or t.max() > 1):
        raise ShapeSpaceError(f"t must be a 1-D array of values in [0, 1], got values from {t.min():g} "
                              f"to {t.max():g}", ErrorCode.RANGE)
    return t


def _endpoints(w0, w1, n):
    return [validate.array(w, name, shape=(n,)) for name, w in (("w0", w0), ("w1", w1))]


def linear_interpolate(w0: ArrayLike, w1: ArrayLike, t: ArrayLike) -> np.ndarray:
    """Plain lerp ``(1 − t) w0 + t w1`` between two faces.

    Parameters
    ----------
    w0, w1 : array_like, shape (n,)
    t : array_like, shape (k,), values in [0, 1]

    Returns
    -------
    ndarray, shape (k, n)
    """
    w0, w1 = _endpoints(w0, w1, np.size(w0))
    t = _times(t)[:, None]
    return (1.0 - t) * w0 + t * w1


def _shell_direction(z0, z1, r0, r1, tc):
    """Unit directions (k, n) from z0/r0 to z1/r1 along a great circle, or None (the radial line)."""
    n = z0.size
    u0, u1 = z0 / r0, z1 / r1
    omega = float(np.arccos(np.clip(u0 @ u1, -1.0, 1.0)))
    if omega < 1e-6:                               # (nearly) the same direction
        return (1.0 - tc) * u0 + tc * u1
    if np.pi - omega >= 1e-6:
        return (np.sin((1.0 - tc) * omega) * u0 + np.sin(tc * omega) * u1) / np.sin(omega)
    if n > 1:                                      # antipodal: turn through a fixed perpendicular axis
        p = np.eye(n)[int(np.argmin(np.abs(u0)))]
        p = p - (p @ u0) * u0
        return np.cos(omega * tc) * u0 + np.sin(omega * tc) * p / np.linalg.norm(p)
    return None


def shell_interpolate(g: FaceGaussian, w0: ArrayLike, w1: ArrayLike, t: ArrayLike) -> np.ndarray:
    """Interpolate between faces along the probability shell (thesis 6.5).

    In whitened coordinates ``z = Λ^{-1/2} Vᵀ (w − μ)`` the direction is slerped from
    z0/‖z0‖ to z1/‖z1‖ and the radius goes linearly from ‖z0‖ to ‖z1‖, so the Mahalanobis
    norm is kept when the endpoints share it (a lerp dips toward the atypical mean).
    Special cases: an endpoint at the mean face (‖z‖ ≈ 0) has no direction, so the path is
    the radial line, identical to the lerp; antipodal endpoints have no unique great
    circle, so the path turns through the whitened axis most perpendicular to z0 (in 1-D,
    where the shell is two points, it falls back to the lerp).  Endpoints are reproduced
    exactly.

    Parameters
    ----------
    g : FaceGaussian
        Over ``n`` sliders.
    w0, w1 : array_like, shape (n,)
    t : array_like, shape (k,), values in [0, 1]

    Returns
    -------
    ndarray, shape (k, n)
    """
    if not isinstance(g, FaceGaussian):
        raise ShapeSpaceError("g must be a FaceGaussian (see fit_face_gaussian)", ErrorCode.TYPE)
    w0, w1 = _endpoints(w0, w1, g.mean.size)
    t = _times(t)
    z0, z1 = g.whiten(w0), g.whiten(w1)
    r0, r1 = float(np.linalg.norm(z0)), float(np.linalg.norm(z1))
    tc = t[:, None]
    z = (1.0 - tc) * z0 + tc * z1                      # the lerp: radial line / 1-D antipodes
    if min(r0, r1) > 1e-12 * max(r0, r1):
        u = _shell_direction(z0, z1, r0, r1, tc)
        if u is not None:
            z = ((1.0 - tc) * r0 + tc * r1) * u / np.linalg.norm(u, axis=1, keepdims=True)
    out = g.unwhiten(z)
    out[t == 0] = w0
    out[t == 1] = w1
    return out


def interpolate(g: FaceGaussian, w0: ArrayLike, w1: ArrayLike, t: ArrayLike, mode: str = "SHELL") -> np.ndarray:
    """In-betweens of two faces by :func:`shell_interpolate` (``"SHELL"``) or :func:`linear_interpolate`.

    Parameters
    ----------
    g : FaceGaussian
        Over ``n`` sliders (unused by ``"LINEAR"``).
    w0, w1 : array_like, shape (n,)
    t : array_like, shape (k,), values in [0, 1]
    mode : {"SHELL", "LINEAR"}

    Returns
    -------
    ndarray, shape (k, n)
    """
    validate.choice(mode, "mode", INTERPOLATIONS, ErrorCode.MODE)
    return shell_interpolate(g, w0, w1, t) if mode == "SHELL" else linear_interpolate(w0, w1, t)


def inbetween_times(frame_a: int, frame_b: int) -> tuple[np.ndarray, np.ndarray]:
    """The frames strictly between ``frame_a`` and ``frame_b`` and their interpolation parameters.

    Parameters
    ----------
    frame_a, frame_b : int
        ``frame_b − frame_a ≥ 2``.

    Returns
    -------
    frames : ndarray of int, shape (k,)
        ``frame_a + 1 … frame_b − 1``.
    t : ndarray, shape (k,)
        ``(frame − frame_a) / (frame_b − frame_a)``, in (0, 1).
    """
    if frame_b - frame_a < 2:
        raise ShapeSpaceError(f"frames {frame_a} and {frame_b} have nothing in between", ErrorCode.RANGE)
    inner = np.arange(frame_a + 1, frame_b)
    return inner, (inner - frame_a) / float(frame_b - frame_a)


def fill_range(keyed: ArrayLike, frame: float, start: int = -1, end: int = -1) -> tuple[int, int]:
    """The two frames to fill between: ``start``/``end`` when given (≥ 0), else the keys around ``frame``.

    Parameters
    ----------
    keyed : array_like, shape (k,)
        Keyed frames (any order, repeats allowed).
    frame : float
        The current frame.
    start, end : int
        A negative value means "the key just before / after ``frame``".

    Returns
    -------
    (int, int)
    """
    if start >= 0 and end >= 0:
        return int(start), int(end)
    keys = np.unique(validate.array(keyed, "keyed", ndim=1))
    frame = validate.finite_scalar(frame, "frame")
    before, after = keys[keys < frame], keys[keys > frame]
    if not before.size or not after.size:
        raise ShapeSpaceError(f"frame {frame:g} is not between two keys", ErrorCode.NO_KEYS)
    a, b = int(round(before[-1])), int(round(after[0]))
    return (a if start < 0 else int(start)), (b if end < 0 else int(end))
