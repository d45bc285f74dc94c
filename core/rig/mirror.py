"""A face's current mirror plane, from where its mirror-paired vertices are now (issue #25 item 2, Symmetric).

A symmetric drag on a linear face reflects a pin's target across the stored mirror map's plane ``x_axis = offset``
in shape-key space (:mod:`core.manipulation.geometry`).  A rig face may be posed — a head bone turned, the object
moved — so a drag through its rig reflects in world space across the plane the face has *now*:
:func:`fit_mirror_plane` estimates it from the evaluated positions of the vertex pairs the map names.

For a mirror-symmetric surface every pair ``(i, m(i))`` satisfies ``p_m = p_i − 2 (n·p_i − d) n``: the
differences ``p_i − p_m`` are all along the plane's normal ``n`` and the midpoints lie on it.  The fit takes
``n`` as the normalised mean of the differences over the pairs whose ``i`` lies on the map's positive side at rest
(one orientation per pair), and ``d`` as the mean of ``n·`` midpoint over those pairs and the centre-line vertices
(the least-squares offset given ``n``).  ``residual`` is the RMS distance between each vertex reflected across the
fitted plane and its mirror vertex: zero for a surface posed symmetrically.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ErrorCode
from ..result import ShapeSpaceError

__all__ = ["MirrorPlane", "fit_mirror_plane"]

#: Pairs the fit reads at most (evenly spaced over the map): the plane of a 27k-vertex head in well under a ms.
MAX_PAIRS = 4096


@dataclass(frozen=True)
class MirrorPlane:
    """The plane ``n·x = d`` (unit ``normal`` (3,), ``offset`` d) and the fit's ``residual`` (RMS, length)
    over ``pairs`` vertex pairs."""

    normal: np.ndarray
    offset: float
    residual: float = 0.0
    pairs: int = 0

    def reflect(self, point: ArrayLike) -> np.ndarray:
        """The reflection (3,) of ``point`` across the plane."""
        p = np.asarray(point, dtype=np.float64).reshape(3)
        return p - 2.0 * (float(self.normal @ p) - self.offset) * self.normal

    def project(self, point: ArrayLike) -> np.ndarray:
        """``point`` moved onto the plane (3,): the midpoint of the point and its reflection (a centre-line pin's
        target in a symmetric drag)."""
        p = np.asarray(point, dtype=np.float64).reshape(3)
        return p - (float(self.normal @ p) - self.offset) * self.normal


def fit_mirror_plane(positions: ArrayLike, mirror: ArrayLike, rest_side: ArrayLike,
                     max_pairs: int = MAX_PAIRS) -> MirrorPlane:
    """The mirror plane of a surface as it is now (module doc).

    Parameters
    ----------
    positions : array_like (V, 3)
        Current (evaluated, world-space) vertex positions.
    mirror : array_like (V,) int
        The mirror map: ``mirror[i]`` is i's mirror vertex, −1 for none, i on the centre line.
    rest_side : array_like (V,)
        A signed coordinate at rest across the map's plane (``rest[:, axis] − offset``): a pair is read once, from
        its vertex on the positive side.
    max_pairs : int
        At most this many pairs are read (evenly spaced).

    Returns
    -------
    MirrorPlane

    Raises
    ------
    ShapeSpaceError
        ``no_mirror`` when the map pairs no two distinct vertices, ``non_finite`` for a non-finite position,
        ``shape`` when the arrays do not match.
    """
    p = np.asarray(positions, dtype=np.float64)
    m = np.asarray(mirror, dtype=np.int64).reshape(-1)
    side = np.asarray(rest_side, dtype=np.float64).reshape(-1)
    if p.ndim != 2 or p.shape[1] != 3 or m.shape != (p.shape[0],) or side.shape != m.shape:
        raise ShapeSpaceError(f"mirror plane: positions {p.shape}, map {m.shape}, sides {side.shape} do not match",
                              ErrorCode.SHAPE)
    idx = np.arange(m.size)
    pairs = np.flatnonzero((m >= 0) & (m != idx) & (side > side[np.clip(m, 0, None)]))
    if pairs.size == 0:
        raise ShapeSpaceError("the mirror map pairs no two vertices: rebuild it (Build Mirror Map)",
                              ErrorCode.NO_MIRROR)
    if pairs.size > max_pairs:
        pairs = pairs[np.linspace(0, pairs.size - 1, max_pairs).astype(np.int64)]
    centre = np.flatnonzero(m == idx)
    if centre.size > max_pairs:
        centre = centre[np.linspace(0, centre.size - 1, max_pairs).astype(np.int64)]
    a, b = p[pairs], p[m[pairs]]
    if not (np.isfinite(a).all() and np.isfinite(b).all() and np.isfinite(p[centre]).all()):
        raise ShapeSpaceError("the surface has a non-finite position: no mirror plane", ErrorCode.NON_FINITE)
    mean = (a - b).mean(axis=0)
    length = float(np.linalg.norm(mean))
    if not length > 0.0:
        raise ShapeSpaceError("the mirror-paired vertices coincide: no mirror plane", ErrorCode.NO_MIRROR)
    n = mean / length
    mids = np.concatenate([0.5 * (a + b), p[centre]]) @ n
    plane = MirrorPlane(n, float(mids.mean()), 0.0, int(pairs.size))
    reflected = a - 2.0 * ((a @ n) - plane.offset)[:, None] * n
    residual = float(np.sqrt(np.mean(np.sum((reflected - b) ** 2, axis=1))))
    return MirrorPlane(n, plane.offset, residual, int(pairs.size))
