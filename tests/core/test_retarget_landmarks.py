"""core.retarget.landmarks: Procrustes, landmark checks and warps, peak landmarks, closest points (thesis 3.5.4).

References: ``scipy Rotation.align_vectors`` (Kabsch) for Procrustes, known similarities and affine maps for the
warps, a dense distance matrix for nearest neighbours.
"""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from core.result import ShapeSpaceError
from core.retarget import closest_points, landmark_layout, landmark_warp, peak_landmarks, procrustes


@pytest.mark.parametrize("seed", [40, 41, 42])
def test_procrustes_recovers_similarity(seed):
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((25, 3))
    R = Rotation.random(random_state=seed).as_matrix()
    s, t = float(rng.uniform(0.3, 3.0)), rng.standard_normal(3) * 4
    Y = s * X @ R.T + t
    s_hat, R_hat, t_hat = procrustes(X, Y)
    assert abs(s_hat - s) <= 1e-10 * s
    np.testing.assert_allclose(R_hat, R, rtol=0, atol=1e-10)
    np.testing.assert_allclose(t_hat, t, rtol=0, atol=1e-10)
    assert np.linalg.det(R_hat) == pytest.approx(1.0, abs=1e-12)


def test_procrustes_coplanar_and_minimal_points():
    rng = np.random.default_rng(43)
    R = Rotation.random(random_state=43).as_matrix()
    for X in (np.column_stack([rng.standard_normal((6, 2)), np.zeros(6)]),     # coplanar
              rng.standard_normal((3, 3))):                                    # 3 points
        Y = 1.5 * X @ R.T + np.array([1.0, -2.0, 0.5])
        s_hat, R_hat, t_hat = procrustes(X, Y)
        assert s_hat == pytest.approx(1.5, rel=1e-10)
        np.testing.assert_allclose(R_hat, R, rtol=0, atol=1e-10)
        np.testing.assert_allclose(t_hat, [1.0, -2.0, 0.5], rtol=0, atol=1e-10)


def test_procrustes_without_scaling():
    rng = np.random.default_rng(44)
    X = rng.standard_normal((10, 3))
    R = Rotation.random(random_state=44).as_matrix()
    Y = X @ R.T + 1.0
    s, R_hat, t = procrustes(X, Y, scaling=False)
    assert s == 1.0
    np.testing.assert_allclose(R_hat, R, rtol=0, atol=1e-10)
    np.testing.assert_allclose(t, np.ones(3), rtol=0, atol=1e-10)


def test_procrustes_reflection_free():
    rng = np.random.default_rng(45)
    X = rng.standard_normal((20, 3)) * np.array([3.0, 2.0, 1.0])
    M = np.diag([1.0, 1.0, -1.0])                        # a mirror: fits exactly, but is not a rotation
    Y = 0.8 * X @ M.T + np.array([0.5, 0.0, -1.0])
    s, R, t = procrustes(X, Y)
    np.testing.assert_allclose(R @ R.T, np.eye(3), rtol=0, atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)
    # reference: the best proper rotation (Kabsch, scipy) on the centred sets; for fixed R the optimal
    # scale is Σ⟨y_i, R x_i⟩ / Σ‖x_i‖² and t = ȳ − s R x̄
    Xc, Yc = X - X.mean(axis=0), Y - Y.mean(axis=0)
    R_ref = Rotation.align_vectors(Yc, Xc)[0].as_matrix()
    s_ref = float(np.sum(Yc * (Xc @ R_ref.T)) / np.sum(Xc ** 2))
    np.testing.assert_allclose(R, R_ref, rtol=0, atol=1e-8)
    assert s == pytest.approx(s_ref, rel=1e-8)
    np.testing.assert_allclose(t, Y.mean(axis=0) - s_ref * R_ref @ X.mean(axis=0), rtol=0, atol=1e-8)
    # the mirror would have fitted better (exactly)
    resid_rot = np.linalg.norm(s * X @ R.T + t - Y)
    assert resid_rot > 1e-3
    assert np.linalg.norm(0.8 * X @ M.T + np.array([0.5, 0.0, -1.0]) - Y) < 1e-12


def test_procrustes_collinear():
    d = np.array([1.0, 2.0, -0.5])
    X = np.outer(np.linspace(-1, 2, 6), d) + np.array([0.3, 0.1, 0.0])
    with pytest.raises(ShapeSpaceError) as exc:
        procrustes(X, X + 1.0)
    assert exc.value.code == "collinear"
    with pytest.raises(ShapeSpaceError) as exc:
        procrustes(np.ones((4, 3)), np.zeros((4, 3)))            # all points coincide
    assert exc.value.code == "collinear"


@pytest.mark.parametrize("m", [0, 1, 2])
def test_procrustes_too_few_points(m):
    rng = np.random.default_rng(46)
    with pytest.raises(ShapeSpaceError) as exc:
        procrustes(rng.standard_normal((m, 3)), rng.standard_normal((m, 3)))
    assert exc.value.code == "too_few"


def test_procrustes_shape_mismatch():
    with pytest.raises(ShapeSpaceError) as exc:
        procrustes(np.zeros((5, 3)), np.zeros((4, 3)))
    assert exc.value.code == "shape"


def test_landmark_warp_maps_landmarks_exactly():
    rng = np.random.default_rng(50)
    src = rng.standard_normal((9, 3))
    R = Rotation.random(random_state=50).as_matrix()
    dst = 1.3 * src @ R.T + np.array([2.0, 0.0, -1.0]) + 0.2 * rng.standard_normal((9, 3))   # non-rigid
    out = landmark_warp(src, dst, src)
    np.testing.assert_allclose(out, dst, rtol=0, atol=1e-8)


def test_landmark_warp_pure_similarity_everywhere():
    rng = np.random.default_rng(51)
    src = rng.standard_normal((8, 3))
    R = Rotation.random(random_state=51).as_matrix()
    s, t = 0.7, np.array([0.0, 3.0, 1.0])
    dst = s * src @ R.T + t
    pts = rng.uniform(-3, 3, (200, 3))
    np.testing.assert_allclose(landmark_warp(src, dst, pts), s * pts @ R.T + t, rtol=0, atol=1e-8)


def test_landmark_warp_affine_reproduced_everywhere():
    # thin-plate spline with a linear polynomial reproduces any affine map exactly (analytic identity)
    rng = np.random.default_rng(52)
    src = rng.standard_normal((10, 3))
    A = np.eye(3) + 0.3 * rng.standard_normal((3, 3))
    b = rng.standard_normal(3)
    pts = rng.uniform(-2, 2, (100, 3))
    np.testing.assert_allclose(landmark_warp(src, src @ A.T + b, pts), pts @ A.T + b, rtol=0, atol=1e-8)


@pytest.mark.parametrize("m", [1, 2])
def test_landmark_warp_too_few(m):
    rng = np.random.default_rng(53)
    with pytest.raises(ShapeSpaceError) as exc:
        landmark_warp(rng.standard_normal((m, 3)), rng.standard_normal((m, 3)), np.zeros((1, 3)))
    assert exc.value.code == "too_few"


def test_landmark_warp_collinear_is_refused():
    t = np.linspace(0.0, 1.0, 6)[:, None]
    line = np.hstack([t, 2 * t, -t])
    rng = np.random.default_rng(55)
    with pytest.raises(ShapeSpaceError) as exc:
        landmark_warp(line, rng.standard_normal((6, 3)), np.zeros((1, 3)))
    assert exc.value.code == "collinear"


@pytest.mark.parametrize("m", [3, 7])
def test_landmark_warp_coplanar_and_three_landmarks_land_exactly(m):
    rng = np.random.default_rng(56)
    src = np.column_stack([rng.standard_normal((m, 2)), np.zeros(m)])       # all in the plane z = 0
    dst = src @ Rotation.from_rotvec([0.2, -0.1, 0.4]).as_matrix().T * 1.3 + 0.05 * rng.standard_normal((m, 3))
    assert landmark_layout(src) == "coplanar"
    np.testing.assert_allclose(landmark_warp(src, dst, src), dst, rtol=0, atol=1e-9)


def test_peak_landmarks_pick_each_shapes_most_moved_vertex():
    rng = np.random.default_rng(57)
    ds = rng.normal(size=(4, 30, 3)) * 0.01
    dt = rng.normal(size=(5, 40, 3)) * 0.01
    for i, (a, b) in enumerate([(3, 7), (11, 20), (25, 39)]):
        ds[i, a] = [1.0, 0, 0]
        dt[i + 1, b] = [0, 2.0, 0]
    ds[3] = 0.0                                                            # an empty source shape
    src, dst, used = peak_landmarks(ds, dt, [(0, 1), (1, 2), (2, 3), (3, 4)])
    np.testing.assert_array_equal(src, [3, 11, 25])
    np.testing.assert_array_equal(dst, [7, 20, 39])
    assert used == [(0, 1), (1, 2), (2, 3)]


def test_landmark_warp_count_mismatch():
    rng = np.random.default_rng(54)
    with pytest.raises(ShapeSpaceError):
        landmark_warp(rng.standard_normal((5, 3)), rng.standard_normal((6, 3)), np.zeros((1, 3)))


def test_closest_points_brute_force():
    rng = np.random.default_rng(60)
    surface = rng.standard_normal((300, 3))
    pts = rng.standard_normal((80, 3)) * 1.5
    idx, dist = closest_points(pts, surface)
    D = np.linalg.norm(pts[:, None, :] - surface[None, :, :], axis=2)
    np.testing.assert_array_equal(idx, np.argmin(D, axis=1))
    np.testing.assert_allclose(dist, D.min(axis=1), rtol=1e-12, atol=1e-14)
    # a point that is a surface vertex maps to itself at distance 0
    idx2, dist2 = closest_points(surface[[7, 123]], surface)
    np.testing.assert_array_equal(idx2, [7, 123])
    np.testing.assert_array_equal(dist2, [0.0, 0.0])
