"""Pose-space confidence (thesis 9.1–9.2): the Gaussian-process variance of the interpolation and the
per-vertex uncertainty, against the GP formulas written out with ``np.linalg.solve`` here."""
import numpy as np
import pytest

from core.posespace.confidence import GPConfidence, gp_variance, heat_map_colors, vertex_uncertainty
from core.result import ShapeSpaceError


def _direct_variance(C, x, eps, noise=0.0, phi=lambda r: np.exp(-r * r)):
    d = lambda A, B: np.sqrt(np.sum((A[:, None] - B[None]) ** 2, axis=-1))   # noqa: E731
    K = phi(eps * d(C, C)) + noise * np.eye(len(C))
    k = phi(eps * d(x, C))
    return 1.0 - np.einsum("mi,mi->m", k, np.linalg.solve(K, k.T).T)


def test_gp_variance_zero_at_centres_one_far_away_and_matches_direct_formula():
    rng = np.random.default_rng(16)
    C = rng.uniform(-1, 1, size=(8, 3))
    np.testing.assert_allclose(gp_variance(C, C, epsilon=1.5), 0.0, atol=1e-9)
    assert np.all(gp_variance(C, C + 100.0, epsilon=1.5) > 1 - 1e-12)
    x = rng.uniform(-1.5, 1.5, size=(4, 5, 3))
    v = gp_variance(C, x, epsilon=1.5)
    assert v.shape == (4, 5) and np.all((v >= 0) & (v <= 1))
    np.testing.assert_allclose(v.ravel(), _direct_variance(C, x.reshape(-1, 3), 1.5), atol=1e-10)
    for kernel, phi in (("inverse_multiquadric", lambda r: 1 / np.sqrt(1 + r * r)),
                        ("inverse_quadratic", lambda r: 1 / (1 + r * r))):
        np.testing.assert_allclose(gp_variance(C, x.reshape(-1, 3), kernel, 2.0),
                                   _direct_variance(C, x.reshape(-1, 3), 2.0, phi=phi), atol=1e-10)
    with_noise = gp_variance(C, x.reshape(-1, 3), epsilon=1.5, noise=0.1)
    np.testing.assert_allclose(with_noise, _direct_variance(C, x.reshape(-1, 3), 1.5, noise=0.1), atol=1e-12)
    assert np.all(gp_variance(C, C, epsilon=1.5, noise=0.1) > 0.01)


def test_gp_variance_is_monotone_along_a_ray_from_a_single_centre():
    conf = GPConfidence.fit(np.array([[0.2, -0.1]]), epsilon=0.7)
    s = np.linspace(0, 6, 50)
    v = conf.variance(np.array([0.2, -0.1]) + s[:, None] * np.array([0.6, 0.8]))
    assert v[0] == pytest.approx(0.0, abs=1e-12) and v[-1] > 0.999
    assert np.all(np.diff(v) > 0)
    np.testing.assert_allclose(v, 1 - np.exp(-2 * (0.7 * s) ** 2), atol=1e-12)   # 1 − k² for one centre


def test_duplicate_centres_get_jitter_and_bad_input_is_named():
    conf = GPConfidence.fit(np.array([[0.0], [0.0], [1.0]]))
    assert conf.jitter > 0 and np.isfinite(conf.variance(np.array([[0.5]]))).all()
    with pytest.raises(ShapeSpaceError, match="centers must have shape"):
        GPConfidence.fit(np.zeros(3))
    with pytest.raises(ShapeSpaceError, match="kernel must be one of"):
        GPConfidence.fit(np.zeros((2, 1)) + [[0], [1]], kernel="thin_plate_spline")
    with pytest.raises(ShapeSpaceError, match="noise"):
        GPConfidence.fit(np.eye(2), noise=-1.0)
    with pytest.raises(ShapeSpaceError, match=r"x must have shape \(\.\.\., 2\)"):
        GPConfidence.fit(np.eye(2)).variance(np.zeros(3))


def test_vertex_uncertainty_scales_with_the_correctives_and_vanishes_for_unmoved_vertices():
    rng = np.random.default_rng(17)
    N, p = 6, 5
    C = rng.uniform(-1, 1, size=(N, 2))
    D = rng.normal(size=(N, p, 3))
    D[:, 1] = 0.0
    conf = GPConfidence.fit(C, epsilon=1.2, noise=1e-3)
    x = np.array([0.3, 0.4])
    sd = vertex_uncertainty(conf, x, D)
    assert sd.shape == (p,) and sd[1] == 0.0 and np.all(sd[[0, 2, 3, 4]] > 0)
    d = np.sqrt(np.sum((C[:, None] - C[None]) ** 2, axis=-1))
    K = np.exp(-(1.2 * d) ** 2) + 1e-3 * np.eye(N)
    for v in range(p):
        s2 = sum(D[:, v, c] @ np.linalg.solve(K, D[:, v, c]) for c in range(3)) / (3 * N)
        assert sd[v] == pytest.approx(np.sqrt(s2 * conf.variance(x)), rel=1e-10, abs=1e-15)
    np.testing.assert_allclose(vertex_uncertainty(conf, C, D), np.sqrt(conf.variance(C))[:, None]
                               * sd[None] / np.sqrt(conf.variance(x)), rtol=1e-10)
    np.testing.assert_allclose(vertex_uncertainty(conf, x, 2 * D), 2 * sd, rtol=1e-12)
    with pytest.raises(ShapeSpaceError, match=r"correctives must have shape \(6, p, 3\)"):
        vertex_uncertainty(conf, x, D[:, :, :2])


def test_heat_map_colors_run_from_blue_to_red():
    sd = np.array([0.0, 0.5, 2.0, 1.0])
    t = sd / 2.0
    ref = np.column_stack([t, 0.2 * (1 - t), 1 - t, np.ones(4)])
    np.testing.assert_allclose(heat_map_colors(sd), ref, rtol=0, atol=1e-15)
    np.testing.assert_allclose(heat_map_colors(np.zeros(3)), [[0.0, 0.2, 1.0, 1.0]] * 3)   # nothing uncertain
    with pytest.raises(ShapeSpaceError) as e:
        heat_map_colors(np.zeros((2, 2)))
    assert e.value.code == "shape"
