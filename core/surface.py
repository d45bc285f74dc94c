"""Closest points on a triangle surface (shared by model transfer's registration and the symmetry tools)."""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["closest_on_triangles"]


def _closest_point_triangle(p, a, b, c):
    """Closest points on triangles (a, b, c) to points p, all (m, 3); returns (point, barycentric (m, 3)).

    Ericson, *Real-Time Collision Detection*, 5.1.5, vectorised.
    """
    ab, ac, ap = b - a, c - a, p - a
    d1 = np.einsum("ij,ij->i", ab, ap)
    d2 = np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3 = np.einsum("ij,ij->i", ab, bp)
    d4 = np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5 = np.einsum("ij,ij->i", ab, cp)
    d6 = np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    m = p.shape[0]
    bary = np.zeros((m, 3))
    done = np.zeros(m, dtype=bool)

    def put(mask, u, v, w):
        nonlocal done
        mask = mask & ~done
        bary[mask, 0], bary[mask, 1], bary[mask, 2] = u[mask], v[mask], w[mask]
        done |= mask

    zero, one = np.zeros(m), np.ones(m)
    with np.errstate(invalid="ignore", divide="ignore"):
        put((d1 <= 0) & (d2 <= 0), one, zero, zero)
        put((d3 >= 0) & (d4 <= d3), zero, one, zero)
        v = d1 / (d1 - d3)
        put((vc <= 0) & (d1 >= 0) & (d3 <= 0), 1 - v, v, zero)
        put((d6 >= 0) & (d5 <= d6), zero, zero, one)
        w = d2 / (d2 - d6)
        put((vb <= 0) & (d2 >= 0) & (d6 <= 0), 1 - w, zero, w)
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        put((va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0), zero, 1 - w, w)
        denom = va + vb + vc
        v = vb / denom
        w = vc / denom
        put(np.ones(m, dtype=bool), 1 - v - w, v, w)
    bary = np.nan_to_num(bary, nan=1.0 / 3.0)
    point = bary[:, :1] * a + bary[:, 1:2] * b + bary[:, 2:] * c
    return point, bary


def closest_on_triangles(points: np.ndarray, verts: np.ndarray, tris: np.ndarray, candidates: int = 10,
                         tree: cKDTree | None = None) -> tuple:
    """Closest point on a triangle surface for each query point.

    Candidate triangles are the ``candidates`` nearest by centroid (plus every triangle of the nearest
    vertex's ring would be exact; centroid candidates are exact for reasonably even meshes).  A candidate is
    skipped for the points it cannot improve: no point of a triangle is nearer than the centroid's distance
    minus the triangle's radius about its centroid (the result is the same as testing every candidate).

    Parameters
    ----------
    points : ndarray (m, 3)
    verts : ndarray (n, 3)
    tris : ndarray of int (f, 3)
    candidates : int
    tree : cKDTree, optional
        A tree over the triangle centroids, to re-use between calls.

    Returns
    -------
    tri : ndarray of int (m,)
        Index into ``tris``.
    bary : ndarray (m, 3)
    point : ndarray (m, 3)
    distance : ndarray (m,)
    """
    P = np.asarray(points, dtype=np.float64)
    if tree is None:
        tree = cKDTree(verts[tris].mean(axis=1))
    k = min(candidates, tris.shape[0])
    dc, cand = tree.query(P, k=k)
    dc, cand = dc.reshape(P.shape[0], k), cand.reshape(P.shape[0], k)
    corners = verts[tris]
    radius = np.linalg.norm(corners - corners.mean(axis=1, keepdims=True), axis=2).max(axis=1)
    best_d = np.full(P.shape[0], np.inf)
    best_t = np.zeros(P.shape[0], dtype=np.int64)
    best_b = np.zeros((P.shape[0], 3))
    best_p = np.zeros_like(P)
    for j in range(k):
        rows = np.flatnonzero(dc[:, j] - radius[cand[:, j]] < best_d)
        if rows.size == 0:
            continue
        t = tris[cand[rows, j]]
        q, b = _closest_point_triangle(P[rows], verts[t[:, 0]], verts[t[:, 1]], verts[t[:, 2]])
        d = np.linalg.norm(q - P[rows], axis=1)
        better = d < best_d[rows]
        r = rows[better]
        best_d[r], best_t[r] = d[better], cand[r, j]
        best_b[r], best_p[r] = b[better], q[better]
    return best_t, best_b, best_p, best_d
