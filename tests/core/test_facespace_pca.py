"""PCA bases, slider maps and compression (core.facespace.pca, thesis 3.4.6, 3.7.5, 3.7.8), checked against
NumPy SVDs and brute-force reconstructions."""
import numpy as np
import pytest

from core import facespace as fs
from core.blendshape import BlendshapeModel, Combination
from core.result import ShapeSpaceError
from facespace_models import random_model


def brute_errors(frames):
    """Max 3-D vertex error of every rank-m PCA reconstruction, from full reconstructions."""
    f = frames.shape[0]
    X = frames.reshape(f, -1)
    Xc = X - X.mean(axis=0)
    U, s, vt = np.linalg.svd(Xc, full_matrices=False)
    out = []
    for m in range(s.size + 1):
        R = Xc - (U[:, :m] * s[:m]) @ vt[:m]
        out.append(np.linalg.norm(R.reshape(f, -1, 3), axis=2).max())
    return np.array(out)


# ------------------------------------------------------------------ PCA maps
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_exact_pca_of_rig_round_trips(seed):
    model = random_model(seed, p=40, n=7)
    basis = fs.pca_from_model(model)
    assert basis.n_components == 7
    np.testing.assert_allclose(basis.components.T @ basis.components, np.eye(7), atol=1e-13)
    A, a = fs.blendshape_to_pca_maps(model, basis)
    P, q = fs.pca_to_blendshape_maps(model, basis)
    assert A.shape == (7, 7) and a.shape == (7,) and P.shape == (7, 7) and q.shape == (7,)
    np.testing.assert_allclose(P @ A, np.eye(7), atol=1e-12)
    w = np.random.default_rng(seed).uniform(0, 1, size=(5, 7))
    c = w @ A.T + a
    np.testing.assert_allclose(c, basis.project(model.evaluate(w)), atol=1e-12)  # c is the projection
    np.testing.assert_allclose(c @ P.T + q, w, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(basis.reconstruct(c).reshape(5, 40, 3), model.evaluate(w), atol=1e-12)


def test_maps_round_trip_for_pca_fitted_to_animation():
    model = random_model(5, p=40, n=5, wide=True)
    w = np.random.default_rng(6).normal(size=(60, 5))
    basis = fs.fit_pca(model.evaluate(w))
    assert basis.n_components == 5
    A, a = fs.blendshape_to_pca_maps(model, basis)
    P, q = fs.pca_to_blendshape_maps(model, basis)
    w2 = np.random.default_rng(7).normal(size=(3, 5))
    np.testing.assert_allclose((w2 @ A.T + a) @ P.T + q, w2, atol=1e-9)


def test_rank_deficient_rig_drops_directions_and_keeps_faces():
    model = random_model(8, p=20, n=4)
    deltas = np.concatenate([model.deltas, model.deltas[:1], np.zeros((1, 20, 3))])
    rig = BlendshapeModel(model.neutral, deltas, list("abcdef"))
    basis = fs.pca_from_model(rig)
    assert basis.n_components == 4
    A, a = fs.blendshape_to_pca_maps(rig, basis)
    P, q = fs.pca_to_blendshape_maps(rig, basis)
    w = np.array([0.1, 0.4, 0.0, 0.3, 0.5, 0.9])
    w2 = P @ (A @ w + a) + q
    np.testing.assert_allclose(rig.evaluate(w2), rig.evaluate(w), atol=1e-12)  # same face, min-norm weights
    assert w2[5] == pytest.approx(0.0, abs=1e-12)


def test_fit_pca_matches_svd_and_options():
    rng = np.random.default_rng(9)
    frames = rng.normal(size=(12, 10, 3))
    basis = fs.fit_pca(frames)
    assert basis.n_components == 11  # 12 centred frames have rank 11
    X = frames.reshape(12, -1)
    np.testing.assert_allclose(basis.mean, X.mean(axis=0))
    np.testing.assert_allclose(basis.reconstruct(basis.project(X)), X, atol=1e-12)
    s = np.linalg.svd(X - X.mean(axis=0), compute_uv=False)[:11]
    np.testing.assert_allclose(basis.variances, s ** 2 / 11, rtol=1e-12)
    assert fs.fit_pca(frames, n_components=3).n_components == 3
    assert fs.fit_pca(frames, tol=s[4] / s[0] * 0.999).n_components == 5


# ------------------------------------------------------------- compression
@pytest.mark.parametrize("seed,p,smooth", [(0, 30, False), (1, 700, False), (2, 900, True)])
def test_compression_errors_match_brute_force(seed, p, smooth):
    model = random_model(seed, p=p, n=8, smooth=smooth)
    w = np.random.default_rng(seed + 50).uniform(0, 1, size=(40, 8))
    ref = brute_errors(model.evaluate(w))
    res = fs.compression_report(model, w, tol=0.3 * ref[0])
    errs = res.diagnostics["errors"]
    assert errs.shape == (9,) and res.diagnostics["animation_rank"] == 8
    np.testing.assert_allclose(errs, ref[:9], rtol=1e-10, atol=1e-12 * model.scale)
    assert res.value == int(np.flatnonzero(ref <= 0.3 * ref[0])[0]) > 0
    assert res.diagnostics["compression_ratio"] == pytest.approx(8 / res.value)
    assert res.diagnostics["rig_rank"] == 8 and res.diagnostics["n_targets"] == 8


def test_three_dimensional_animation_needs_three_components():
    model = random_model(3, p=50, n=10, wide=True)
    rng = np.random.default_rng(4)
    w = 0.3 + rng.normal(size=(80, 3)) @ rng.normal(size=(3, 10))
    res = fs.compression_report(model, w, tol=1e-9 * model.scale)
    assert res.value == 3 and res.success
    assert res.diagnostics["animation_rank"] == 3 and res.diagnostics["rig_rank"] == 10
    assert res.diagnostics["errors"][2] > 1e-3 * model.scale
    assert res.diagnostics["compression_ratio"] == pytest.approx(10 / 3)


def test_compression_includes_correctives_and_reports_unmet_tolerance():
    model = random_model(6, p=25, n=4)
    model.combinations.append(Combination("c01", (0, 1), np.random.default_rng(1).normal(size=(25, 3))))
    w = np.random.default_rng(2).uniform(0, 1, size=(30, 4))
    res = fs.compression_report(model, w, tol=1e-6, max_components=2)
    np.testing.assert_allclose(res.diagnostics["errors"], brute_errors(model.evaluate(w))[:3], rtol=1e-10)
    assert res.value is None and res.status == -1 and res.errors()[0].code == "tolerance_not_met"
    assert res.diagnostics["animation_rank"] == 5


def test_static_animation_needs_no_component():
    model = random_model(7)
    res = fs.compression_report(model, np.full((5, 6), 0.25), tol=1e-9)
    assert res.value == 0 and res.diagnostics["animation_rank"] == 0
    assert res.diagnostics["compression_ratio"] == np.inf
    np.testing.assert_array_equal(res.diagnostics["errors"], [0.0])


def test_compression_bad_input():
    model = random_model(0)
    w = np.zeros((5, 6))
    with pytest.raises(ShapeSpaceError, match="weights must have shape"):
        fs.compression_report(model, np.zeros((5, 4)), tol=1.0)
    with pytest.raises(ShapeSpaceError, match="at least 2 frames") as err:
        fs.compression_report(model, w[:1], tol=1.0)
    assert err.value.code == "too_few"
    for bad in (0.0, -1.0, np.nan):
        with pytest.raises(ShapeSpaceError, match="tol"):
            fs.compression_report(model, w, tol=bad)
    empty = BlendshapeModel(np.zeros((3, 3)), np.zeros((0, 3, 3)), [])
    with pytest.raises(ShapeSpaceError, match="empty rig"):
        fs.compression_report(empty, np.zeros((5, 0)), tol=1.0)
    with pytest.raises(ShapeSpaceError, match="at least 2 frames"):
        fs.fit_pca(np.zeros((1, 9)))
    with pytest.raises(ShapeSpaceError, match="frames must have shape"):
        fs.fit_pca(np.zeros((4, 10)))
    with pytest.raises(ShapeSpaceError, match="basis.mean"):
        fs.blendshape_to_pca_maps(model, fs.pca_from_model(random_model(0, p=31)))
    with pytest.raises(ShapeSpaceError, match="targets must have shape"):
        fs.from_whole_face(np.zeros((4, 3)), np.zeros((2, 5, 3)), ["a", "b"])
    with pytest.raises(ShapeSpaceError, match="BlendshapeModel"):
        fs.pca_from_model(np.zeros((3, 3)))
    with pytest.raises(ShapeSpaceError, match="c must have shape"):
        fs.delta_weights(np.zeros((3, 0)))
    with pytest.raises(ShapeSpaceError, match="w must have shape"):
        fs.whole_face_weights(1.0)


def test_animation_pca_matches_pca_of_the_formed_frames():
    from core.facespace.pca import animation_pca
    rng = np.random.default_rng(21)
    p, n, f = 40, 6, 30
    model = BlendshapeModel(rng.normal(size=(p, 3)), rng.normal(size=(n, p, 3)), [f"t{i}" for i in range(n)])
    W = rng.uniform(0, 1, size=(f, n))
    basis = animation_pca(model, W)
    X = model.evaluate(W).reshape(f, -1)
    Xc = X - X.mean(axis=0)
    _, s, vt = np.linalg.svd(Xc, full_matrices=False)
    np.testing.assert_allclose(basis.mean, X.mean(axis=0), atol=1e-12)
    np.testing.assert_allclose(basis.variances, s[:n] ** 2 / (f - 1), rtol=1e-10)
    np.testing.assert_allclose(np.abs(basis.components.T @ vt[:n].T), np.eye(n), atol=1e-8)


def _rig(n=4, p=30, seed=0):
    from core.blendshape import BlendshapeModel
    rng = np.random.default_rng(seed)
    return BlendshapeModel(rng.normal(size=(p, 3)), rng.normal(size=(n, p, 3)), [f"k{i}" for i in range(n)])


def test_pca_sliders_grow_a_unit_so_every_frame_stays_within_the_limit():
    model = _rig()
    W = np.full((200, 4), 0.01) + 0.002 * np.random.default_rng(1).normal(size=(200, 4))
    W[100] = [1.0, 0.0, 0.0, 0.0]                          # a spike many standard deviations out
    basis = fs.animation_pca(model, W)
    plain, held = fs.pca_sliders(model, basis), fs.pca_sliders(model, basis, W, 10.0)
    assert np.abs(plain.slider_values(W)).max() > 10.0
    S = held.slider_values(W)
    assert np.abs(S).max() <= 10.0 * (1 + 1e-12)
    # the keys still reproduce every frame: rest + Σ s_i (key_i − rest) = the frame's projection
    faces = held.rest[None] + np.einsum("fm,mpc->fpc", S, held.keys - held.rest[None])
    frames = model.neutral[None] + np.einsum("fn,npc->fpc", W, model.deltas)
    np.testing.assert_allclose(faces, frames, atol=1e-9 * np.abs(frames).max())
    np.testing.assert_array_equal(held.unit >= plain.unit, True)


def test_pca_sliders_of_an_empty_basis_have_no_keys():
    from core.blendshape import BlendshapeModel
    model = BlendshapeModel(np.ones((5, 3)), np.zeros((2, 5, 3)), ["a", "b"])
    sliders = fs.pca_sliders(model, fs.pca_from_model(model))
    assert sliders.keys.shape == (0, 5, 3) and sliders.A.shape == (0, 2)
