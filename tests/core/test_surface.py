"""Closest points on a triangle surface (core/surface.py) against independent answers: a brute-force search over
every triangle, and fresh queries for the warm-started ones of an iterative closest point."""
import numpy as np

from core.surface import TriangleSurface, closest_on_triangles
from test_authoring_parts import _sphere as uv_sphere


def _sphere(n_lat=14, n_lon=22):
    """A bumpy closed surface (uneven triangles): (verts, tris)."""
    d, T = uv_sphere(n_lat, n_lon)
    return d * (1.0 + 0.15 * np.sin(3 * d[:, :1]) * np.cos(2 * d[:, 1:2])), T


def _brute_force(points, V, T):
    """Closest point on every triangle by dense sampling of barycentric coordinates: the smallest distance."""
    s = np.linspace(0, 1, 21)
    u, v = np.meshgrid(s, s)
    keep = u + v <= 1
    B = np.stack([1 - u[keep] - v[keep], u[keep], v[keep]], axis=1)             # (b, 3)
    samples = np.einsum("bk,fkc->fbc", B, V[T]).reshape(-1, 3)
    return np.min(np.linalg.norm(points[:, None, :] - samples[None], axis=2), axis=1)


def test_closest_points_match_a_brute_force_search():
    """With every triangle a candidate the distance is the surface distance (dense sampling is within its
    spacing above it) and the point lies on the returned triangle at the returned barycentric coordinates."""
    V, T = _sphere()
    rng = np.random.default_rng(3)
    P = rng.standard_normal((25, 3)) * 0.8
    tri, bary, point, dist = closest_on_triangles(P, V, T, candidates=T.shape[0])
    ref = _brute_force(P, V, T)
    spacing = np.linalg.norm(V[T[:, 1]] - V[T[:, 0]], axis=1).max() / 20
    assert np.all(dist <= ref + 1e-12) and np.all(ref - dist <= spacing)
    assert np.allclose(np.einsum("mk,mkc->mc", bary, V[T[tri]]), point, atol=1e-12)
    assert np.allclose(np.linalg.norm(point - P, axis=1), dist, atol=1e-12)
    assert np.all(bary >= -1e-12) and np.allclose(bary.sum(axis=1), 1.0)


def test_warm_queries_give_exactly_the_fresh_results():
    """An ICP-like sequence of queries of the same points (small steps towards the surface, sometimes a jump
    that changes a point's candidate set): the warm-started queries return exactly what fresh queries return."""
    V, T = _sphere()
    rng = np.random.default_rng(7)
    P = V[rng.choice(len(V), 150, replace=False)] * 1.08 + 0.02 * rng.standard_normal((150, 3))
    surface = TriangleSurface(V, T)
    warm = {}
    for step in range(12):
        fresh = closest_on_triangles(P, V, T, candidates=6, tree=surface.tree)
        got = surface.closest(P, candidates=6, warm=warm)
        for a, b in zip(fresh, got):
            assert np.array_equal(a, b), step
        P = P + 0.3 * (fresh[2] - P)                        # towards the surface
        if step % 4 == 3:
            P[::7] += 0.2 * rng.standard_normal(P[::7].shape)   # some points jump (new candidate sets)
    assert warm["k"] == 6
