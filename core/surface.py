"""Closest points on a triangle surface (shared by model transfer's registration and the symmetry tools)."""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["TriangleSurface", "closest_on_triangles"]


def _closest_point_triangle(p, a, b, c):
    """Closest points on triangles (a, b, c) to points p, all (m, 3); returns (point, barycentric (m, 3)).

    Ericson, *Real-Time Collision Detection*, 5.1.5, vectorised: the first of the Voronoi regions (three
    corners, three edges, the face) whose test holds gives the barycentric coordinates.
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
    with np.errstate(invalid="ignore", divide="ignore"):
        regions = [(d1 <= 0) & (d2 <= 0), (d3 >= 0) & (d4 <= d3), (vc <= 0) & (d1 >= 0) & (d3 <= 0),
                   (d6 >= 0) & (d5 <= d6), (vb <= 0) & (d2 >= 0) & (d6 <= 0),
                   (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)]
        v_ab = d1 / (d1 - d3)
        w_ac = d2 / (d2 - d6)
        w_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        denom = va + vb + vc
        v = vb / denom
        w = vc / denom
        bary = np.stack([np.select(regions, [1.0, 0.0, 1 - v_ab, 0.0, 1 - w_ac, 0.0], 1 - v - w),
                         np.select(regions, [0.0, 1.0, v_ab, 0.0, 0.0, 1 - w_bc], v),
                         np.select(regions, [0.0, 0.0, 0.0, 1.0, w_ac, w_bc], w)], axis=1)
    bary = np.nan_to_num(bary, nan=1.0 / 3.0)
    point = bary[:, :1] * a + bary[:, 1:2] * b + bary[:, 2:] * c
    return point, bary


class TriangleSurface:
    """A triangle surface prepared for repeated closest-point queries: a tree of the triangle centroids and
    each triangle's radius about its centroid, built once.

    Parameters
    ----------
    verts : ndarray (n, 3)
    tris : ndarray of int (f, 3)
    tree : cKDTree, optional
        A tree over the triangle centroids (built when not given).
    """

    def __init__(self, verts: np.ndarray, tris: np.ndarray, tree: cKDTree | None = None):
        self.verts = np.asarray(verts, dtype=np.float64)
        self.tris = np.asarray(tris, dtype=np.int64)
        corners = self.verts[self.tris]
        self.centroids = corners.mean(axis=1)
        self.tree = tree if tree is not None else cKDTree(self.centroids)
        self.radius = np.linalg.norm(corners - self.centroids[:, None, :], axis=2).max(axis=1)

    def nearest(self, points: np.ndarray, k: int) -> tuple:
        """The ``k`` triangles nearest to each point by centroid, nearest first: distances and indices (m, k)."""
        m = points.shape[0]
        k = min(k, self.tris.shape[0])
        dc, cand = self.tree.query(points, k=k)
        return dc.reshape(m, k), cand.reshape(m, k)

    def closest(self, points: np.ndarray, candidates: int = 10, warm: dict | None = None) -> tuple:
        """Closest point on the surface of each query point, among the ``candidates`` triangles nearest by
        centroid (see :func:`closest_on_triangles`).

        A candidate is skipped for the points it cannot improve (its centroid distance minus its radius is not
        below the nearest point found so far).  The result is the nearest candidate, the one nearer by centroid
        among equally near ones.

        ``warm`` (a dict the caller keeps between queries of the same m points, empty at first: the steps of an
        iterative closest point) makes the same queries cheaper with the same results:

        - a point keeps its candidate set while it cannot have changed: while the point has moved by less than
          half the gap between its ``k``-th and ``(k+1)``-th nearest centroid distances when the set was found
          (no centroid can have overtaken another); only the other points query the tree again;
        - the distance to a triangle is 1-Lipschitz in the point, so a candidate's distance found before, less
          how far the point has moved since, bounds it from below: candidates whose bound exceeds the nearest
          distance found are skipped (near convergence only the previous nearest triangle is tested).

        Returns
        -------
        tri : ndarray of int (m,)
        bary : ndarray (m, 3)
        point : ndarray (m, 3)
        distance : ndarray (m,)
        """
        P = np.asarray(points, dtype=np.float64)
        if warm is not None:
            return self._closest_warm(P, min(candidates, self.tris.shape[0]), warm)
        m = P.shape[0]
        dc, cand = self.nearest(P, candidates)
        best_d = np.full(m, np.inf)
        best_t = np.zeros(m, dtype=np.int64)
        best_b = np.zeros((m, 3))
        best_p = np.zeros_like(P)
        for j in range(cand.shape[1]):
            rows = np.flatnonzero(dc[:, j] - self.radius[cand[:, j]] < best_d)
            if rows.size == 0:
                continue
            d, b, q = self._test(P[rows], cand[rows, j])
            better = d < best_d[rows]
            r = rows[better]
            best_d[r], best_t[r] = d[better], cand[r, j]
            best_b[r], best_p[r] = b[better], q[better]
        return best_t, best_b, best_p, best_d

    def _test(self, P: np.ndarray, tri: np.ndarray) -> tuple:
        """Distance, barycentric coordinates and closest point of each point ``P`` (m, 3) on its triangle."""
        t = self.tris[tri]
        V = self.verts
        q, b = _closest_point_triangle(P, V[t[:, 0]], V[t[:, 1]], V[t[:, 2]])
        return np.linalg.norm(q - P, axis=1), b, q

    def _closest_warm(self, P: np.ndarray, k: int, warm: dict) -> tuple:
        """:meth:`closest` with a ``warm`` state: the candidate of smallest lower bound is tested first, then
        every candidate whose bound does not exceed that distance, all at once; the nearest wins (among equally
        near ones, the one nearer by centroid: the order a fresh query tests them in)."""
        m = P.shape[0]
        cand, lower = self._warm_candidates(P, k, warm)
        rows = np.arange(m)
        col = np.argmin(lower, axis=1)
        d, b, q = self._test(P, cand[rows, col])
        more = lower <= d[:, None]
        more[rows, col] = False
        lower[rows, col] = d
        r2, c2 = np.nonzero(more)
        if r2.size:
            d2, b2, q2 = self._test(P[r2], cand[r2, c2])
            lower[r2, c2] = d2
            dc2 = self._centroid_distance(P[r2], cand[r2, c2])
            o = np.lexsort((c2, dc2, d2, r2))
            f = o[np.r_[True, r2[o][1:] != r2[o][:-1]]]                  # each point's best other candidate
            r = r2[f]
            dc0 = self._centroid_distance(P[r], cand[r, col[r]])
            win = (d2[f] < d[r]) | ((d2[f] == d[r]) & ((dc2[f] < dc0) | ((dc2[f] == dc0) & (c2[f] < col[r]))))
            r, f = r[win], f[win]
            d[r], b[r], q[r], col[r] = d2[f], b2[f], q2[f], c2[f]
        warm["lower"], warm["at"] = lower, P.copy()
        return cand[rows, col], b, q, d

    def _centroid_distance(self, P: np.ndarray, tri: np.ndarray) -> np.ndarray:
        return np.linalg.norm(P - self.centroids[tri], axis=1)

    def _warm_candidates(self, P: np.ndarray, k: int, warm: dict) -> tuple:
        """Candidate sets of :meth:`closest` with ``warm``: triangles and lower bounds of the distances to them,
        (m, k) each (in the order the sets were found)."""
        m = P.shape[0]
        if warm.get("k") != k or warm["anchor"].shape != P.shape:
            warm.update(k=k, anchor=P.copy(), cand=np.zeros((m, k), dtype=np.int64), gap=np.full(m, -1.0),
                        lower=np.full((m, k), -np.inf), at=P.copy())
        moved = np.linalg.norm(P - warm["at"], axis=1)
        # a margin far above rounding (coordinates × 1e-16) and far below any distance that matters
        slack = 1e-9 * (self.radius.max(initial=0.0) + np.abs(P).max(initial=0.0))
        lower = warm["lower"] - (moved + slack)[:, None]
        redo = ~(2.0 * np.linalg.norm(P - warm["anchor"], axis=1) < 0.99 * warm["gap"])
        if redo.any():
            kk = min(k + 1, self.tris.shape[0])
            dq, cq = self.tree.query(P[redo], k=kk)
            dq, cq = dq.reshape(-1, kk), cq.reshape(-1, kk)
            warm["cand"][redo] = cq[:, :k]
            warm["anchor"][redo] = P[redo]
            warm["gap"][redo] = dq[:, k] - dq[:, k - 1] if kk > k else np.inf
            lower[redo] = dq[:, :k] - self.radius[cq[:, :k]]
        return warm["cand"], lower


def closest_on_triangles(points: np.ndarray, verts: np.ndarray, tris: np.ndarray, candidates: int = 10,
                         tree: cKDTree | None = None) -> tuple:
    """Closest point on a triangle surface for each query point.

    Candidate triangles are the ``candidates`` nearest by centroid (plus every triangle of the nearest
    vertex's ring would be exact; centroid candidates are exact for reasonably even meshes).  A candidate is
    skipped for the points it cannot improve: no point of a triangle is nearer than the centroid's distance
    minus the triangle's radius about its centroid (the result is the same as testing every candidate).
    For repeated queries on one surface use :class:`TriangleSurface`.

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
    return TriangleSurface(verts, tris, tree).closest(points, candidates)
