"""Pure geometry of picking and mirroring pins: no Blender data, so the core tier tests it with analytic answers.

- :func:`ray_hit` — the nearest triangle a ray hits (picking a pin on a surface);
- :func:`pin_surface_positions` — pin positions from the positions of their vertices;
- :func:`reflect_point`, :func:`symmetric_target` — a point reflected across a mirror plane ``(axis, offset)``,
  and a centre-line pin's target moved onto it;
- :func:`mirror_pin` — a pin's mirror pin through a vertex mirror map (:class:`core.symmetry.MirrorMap`).
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ErrorCode
from ..result import ShapeSpaceError
from ..symmetry import MirrorMap
from .pins import Pin

__all__ = ["ray_hit", "pin_surface_positions", "reflect_point", "symmetric_target", "mirror_pin"]


def ray_hit(origin: ArrayLike, direction: ArrayLike, co: np.ndarray, tris: np.ndarray) -> tuple | None:
    """The nearest triangle a ray hits: ``(triangle index, barycentric (3,), hit point (3,))`` or None.

    All triangles at once in numpy: the triangles are projected on the plane across the ray, the ray's
    point is tested against each (signed areas), the hit's depth is interpolated.  ``co`` (p, 3) and the ray
    in the same space; ``direction`` need not be unit length.
    """
    o = np.asarray(origin, dtype=np.float64)
    d = np.asarray(direction, dtype=np.float64)
    length = float(np.linalg.norm(d))
    if not np.isfinite(length) or length == 0.0 or not len(tris):
        return None
    d = d / length
    u = np.cross(d, (1.0, 0.0, 0.0) if abs(d[0]) < 0.9 else (0.0, 1.0, 0.0))
    u /= np.linalg.norm(u)
    w = np.cross(d, u)
    rel = co - o
    x, y, z = rel @ u, rel @ w, rel @ d
    X, Y = x[tris], y[tris]
    a0 = X[:, 1] * Y[:, 2] - X[:, 2] * Y[:, 1]
    a1 = X[:, 2] * Y[:, 0] - X[:, 0] * Y[:, 2]
    a2 = X[:, 0] * Y[:, 1] - X[:, 1] * Y[:, 0]
    total = a0 + a1 + a2
    inside = (((a0 >= 0) & (a1 >= 0) & (a2 >= 0)) | ((a0 <= 0) & (a1 <= 0) & (a2 <= 0))) & (total != 0)
    cand = np.flatnonzero(inside)
    if not cand.size:
        return None
    bary = np.stack([a0[cand], a1[cand], a2[cand]], axis=1) / total[cand, None]
    depth = np.einsum("ij,ij->i", bary, z[tris[cand]])
    ahead = depth > 0
    if not ahead.any():
        return None
    best = int(np.flatnonzero(ahead)[np.argmin(depth[ahead])])
    b = np.clip(bary[best], 0.0, 1.0)
    b = b / b.sum()
    return int(cand[best]), b, b @ co[tris[cand[best]]]


def pin_surface_positions(idx: np.ndarray, bary: np.ndarray, vertex_positions: np.ndarray,
                          verts: np.ndarray | None = None) -> np.ndarray:
    """Pin positions ``Σ bary · position[idx]`` (k, 3) from the positions (m, 3) of the sorted vertices ``verts``."""
    pos = np.asarray(vertex_positions, dtype=np.float64)
    rows = idx if verts is None else np.searchsorted(verts, idx)
    return np.einsum("kc,kcx->kx", bary, pos[rows])


def reflect_point(point: ArrayLike, plane: tuple) -> np.ndarray:
    """The reflection (3,) of a point (shape-key / rest object space) across ``x_axis = offset``:
    ``x_axis' = 2·offset − x_axis``."""
    out = np.array(point, dtype=np.float64).reshape(3)
    axis, offset = plane
    out[axis] = 2.0 * offset - out[axis]
    return out


def symmetric_target(target: ArrayLike, plane: tuple) -> np.ndarray:
    """A centre-line pin's target in a symmetric drag: the closest point to both the target and its reflection
    (``(t + R t) / 2``: the target moved onto the mirror plane)."""
    out = np.array(target, dtype=np.float64).reshape(3)
    out[plane[0]] = plane[1]
    return out


def mirror_pin(pin: Pin, mmap: MirrorMap, what: str = "the pin") -> Pin | None:
    """The mirror of a surface point: ``Σ bᵢ m(vᵢ)`` (the same weights on the mirror vertices).

    Returns None when the point is its own mirror (on the centre line: the same vertices with the same
    weights).  Refused (code ``no_mirror``) when one of its vertices has no mirror in ``mmap``.
    """
    mirror = mmap.mirror
    verts = [int(v) for v in pin.vertices]
    if any(v < 0 or v >= len(mirror) for v in verts):
        raise ShapeSpaceError(f"{what} names a vertex outside the mirror map's {len(mirror)} vertices: rebuild the "
                              "mirror map", ErrorCode.STALE_MIRROR_MAP)
    unmapped = [v for v in verts if mirror[v] < 0]
    if unmapped:
        raise ShapeSpaceError(f"{what} sits on vertex {unmapped[0]}, which has no mirror in the mirror map: pin "
                              "elsewhere, or rebuild the map (Topology from a centre edge, or a larger tolerance)",
                              ErrorCode.NO_MIRROR)
    twin = Pin(tuple(int(mirror[v]) for v in verts), tuple(float(b) for b in pin.weights))

    def spread(p):
        out = {}
        for v, b in zip(p.vertices, p.weights):
            if b != 0.0:
                out[v] = out.get(v, 0.0) + b
        return out

    a, b = spread(pin), spread(twin)
    if a.keys() == b.keys() and all(abs(a[v] - b[v]) <= 1e-6 for v in a):
        return None
    return twin
