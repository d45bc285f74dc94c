"""Linear and shell in-betweens (core.facespace.shell, thesis 6.5): norms against the fitted Gaussian."""
import numpy as np
import pytest

from core.facespace import fit_face_gaussian, linear_interpolate, shell_interpolate
from core.result import ShapeSpaceError
from facespace_models import correlated_faces


# ------------------------------------------------------------------ shell interpolation
def _equal_norm_pair(g, rng, radius):
    z0, z1 = rng.normal(size=(2, g.mean.size))
    return g.unwhiten(radius * z0 / np.linalg.norm(z0)), g.unwhiten(radius * z1 / np.linalg.norm(z1))


def test_shell_keeps_the_norm_and_linear_collapses_toward_the_mean():
    rng = np.random.default_rng(6)
    W, _ = correlated_faces(rng, n=8)
    g = fit_face_gaussian(W)
    w0, w1 = _equal_norm_pair(g, rng, g.shell_radius)
    t = np.linspace(0.0, 1.0, 11)
    shell, lin = shell_interpolate(g, w0, w1, t), linear_interpolate(w0, w1, t)
    assert shell.shape == lin.shape == (11, 8)
    np.testing.assert_allclose(g.face_norm(shell), g.shell_radius, rtol=1e-10)
    assert np.array_equal(shell[0], w0) and np.array_equal(shell[-1], w1)
    assert np.array_equal(lin[0], w0) and np.array_equal(lin[-1], w1)
    z0, z1 = g.whiten(w0), g.whiten(w1)
    assert g.face_norm(lin[5]) == pytest.approx(np.linalg.norm(z0 + z1) / 2, rel=1e-10)
    assert g.face_norm(lin[5]) < g.shell_radius - 1e-3
    # the path is a great circle in whitened space: constant angular speed
    Z = g.whiten(shell)
    ang = np.arccos(np.clip(np.sum(Z[:-1] * Z[1:], axis=1) / g.shell_radius ** 2, -1, 1))
    np.testing.assert_allclose(ang, ang[0], rtol=1e-6)


def test_shell_radius_goes_linearly_between_unequal_norms():
    rng = np.random.default_rng(7)
    g = fit_face_gaussian(correlated_faces(rng, n=5)[0])
    w0 = g.unwhiten(np.array([1.0, 0, 0, 0, 0]))
    w1 = g.unwhiten(np.array([0, 3.0, 0, 0, 0]))
    t = np.array([0.0, 0.25, 0.5, 1.0])
    np.testing.assert_allclose(g.face_norm(shell_interpolate(g, w0, w1, t)), 1 + 2 * t, rtol=1e-10)
    same_dir = shell_interpolate(g, w0, g.unwhiten(np.array([4.0, 0, 0, 0, 0])), t)
    np.testing.assert_allclose(same_dir, linear_interpolate(w0, g.unwhiten(np.array([4.0, 0, 0, 0, 0])), t),
                               atol=1e-10)


def test_shell_special_cases_antipodal_and_mean_endpoint():
    rng = np.random.default_rng(8)
    g = fit_face_gaussian(correlated_faces(rng, n=4)[0])
    z = np.array([0.5, -1.0, 2.0, 0.3])
    w0, w1 = g.unwhiten(z), g.unwhiten(-z)
    t = np.linspace(0, 1, 9)
    path = shell_interpolate(g, w0, w1, t)
    assert np.isfinite(path).all()
    np.testing.assert_allclose(g.face_norm(path), np.linalg.norm(z), rtol=1e-10)
    Zm = g.whiten(path[4])
    assert abs(Zm @ z) < 1e-9 * np.linalg.norm(z) ** 2        # halfway: perpendicular to both ends
    # an endpoint at the mean face has no direction: the radial line, same as the lerp
    np.testing.assert_allclose(shell_interpolate(g, g.mean, w1, t), linear_interpolate(g.mean, w1, t), atol=1e-12)
    np.testing.assert_allclose(shell_interpolate(g, g.mean, g.mean, t), np.tile(g.mean, (9, 1)), atol=1e-12)
    # 1-D: the shell is two points, so antipodal ends fall back to the lerp
    g1 = fit_face_gaussian(rng.normal(size=(100, 1)))
    a, b = g1.unwhiten([1.0]), g1.unwhiten([-1.0])
    np.testing.assert_allclose(shell_interpolate(g1, a, b, t), linear_interpolate(a, b, t), atol=1e-12)


def test_shell_bad_input():
    g = fit_face_gaussian(np.random.default_rng(9).normal(size=(50, 3)))
    with pytest.raises(ShapeSpaceError, match=r"w1 must have shape \(3,\)"):
        shell_interpolate(g, np.zeros(3), np.zeros(4), [0.5])
    with pytest.raises(ShapeSpaceError, match="t must be"):
        shell_interpolate(g, np.zeros(3), np.ones(3), [1.5])
    with pytest.raises(ShapeSpaceError, match="FaceGaussian"):
        shell_interpolate(None, np.zeros(3), np.ones(3), [0.5])
