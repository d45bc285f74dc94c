"""Whole-face / delta / PCA conversions, compression and target diagnostics (core.facespace)."""
import numpy as np
import pytest
from scipy.optimize import minimize

from core import facespace as fs
from core.blendshape import BlendshapeModel, Combination
from core.result import ShapeSpaceError


def random_model(seed=0, p=30, n=6, wide=False, smooth=False):
    rng = np.random.default_rng(seed)
    neutral = rng.normal(size=(p, 3))
    if smooth:  # displacements vary smoothly over the vertices, like a real face
        centres = rng.uniform(-1.5, 1.5, size=(n, 3))
        fall = np.exp(-((neutral[None] - centres[:, None]) ** 2).sum(axis=2))
        deltas = fall[..., None] * rng.normal(size=(n, 1, 3)) * 0.2
    else:
        deltas = rng.normal(size=(n, p, 3)) * 0.1
    kw = dict(slider_min=np.full(n, -100.0), slider_max=np.full(n, 100.0)) if wide else {}
    return BlendshapeModel(neutral, deltas, [f"key{k}" for k in range(n)], **kw)


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


# ------------------------------------------------------------ whole-face form
@pytest.mark.parametrize("seed", [0, 1])
def test_delta_whole_delta_round_trip(seed):
    model = random_model(seed)
    targets, neutral = fs.to_whole_face(model)
    assert targets.shape == (6, 30, 3) and neutral.shape == (30, 3)
    for k in range(6):
        np.testing.assert_array_equal(targets[k], model.neutral + model.deltas[k])
    back = fs.from_whole_face(neutral, targets, model.names)
    assert back.names == model.names
    np.testing.assert_allclose(back.deltas, model.deltas, rtol=0, atol=1e-12 * np.abs(model.deltas).max())
    again, _ = fs.to_whole_face(back)
    np.testing.assert_allclose(again, targets, rtol=0, atol=1e-12 * np.abs(targets).max())


def test_whole_face_weights_reproduce_faces():
    model = random_model(2)
    targets, b0 = fs.to_whole_face(model)
    w = np.random.default_rng(3).uniform(0, 1, size=(4, 6))
    c = fs.whole_face_weights(w)
    assert c.shape == (4, 7)
    np.testing.assert_allclose(c.sum(axis=1), 1.0, atol=1e-15)
    faces = c[:, 0, None, None] * b0 + np.einsum("fk,kpc->fpc", c[:, 1:], targets)
    np.testing.assert_allclose(faces, model.evaluate(w), atol=1e-12)
    back, scale = fs.delta_weights(c)
    np.testing.assert_allclose(back, w, atol=1e-15)
    np.testing.assert_allclose(scale, 1.0, atol=1e-15)
    assert fs.whole_face_weights(w[0]).shape == (7,)


def test_nonconvex_whole_face_weights_scale_the_neutral():
    model = random_model(4)
    targets, b0 = fs.to_whole_face(model)
    c = np.array([0.7, 0.5, -0.2, 0.9, 0.0, 0.3, 0.1])  # sums to 2.3
    w, scale = fs.delta_weights(c)
    assert scale == pytest.approx(2.3)
    face = c[0] * b0 + np.einsum("k,kpc->pc", c[1:], targets)
    np.testing.assert_allclose(face, scale * b0 + np.einsum("k,kpc->pc", w, model.deltas), atol=1e-12)


# ----------------------------------------------------------- convex projection
def qp_projection(w, lo, hi):
    """Reference: quadprog on min ½|x − w|² s.t. lo ≤ x ≤ hi, Σx ≤ 1."""
    quadprog = pytest.importorskip("quadprog")
    n = w.size
    rows, rhs = [np.eye(n), -np.ones((1, n))], [lo, [-1.0]]
    fin = np.isfinite(hi)
    rows.insert(1, -np.eye(n)[fin])
    rhs.insert(1, -hi[fin])
    return quadprog.solve_qp(np.eye(n), w, np.vstack(rows).T, np.concatenate(rhs), 0)[0]


@pytest.mark.parametrize("seed", range(8))
def test_projection_matches_quadprog_and_kkt(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 12))
    lo = rng.uniform(-0.3, 0.0, n) if seed % 2 else np.zeros(n)
    hi = np.where(rng.uniform(size=n) < 0.3, np.inf, rng.uniform(0.2, 1.0, n))
    w = rng.uniform(-0.5, 1.5, size=(5, n))
    x = fs.project_convex(w, lo, hi)
    for t in range(5):
        np.testing.assert_allclose(x[t], qp_projection(w[t], lo, hi), atol=1e-9)
        np.testing.assert_allclose(fs.project_convex(w[t], lo, hi), x[t], atol=0)  # vectorised = per row
        # KKT: x = clip(w − λ), λ ≥ 0, complementary slackness
        assert np.all(x[t] >= lo - 1e-15) and np.all(x[t] <= hi + 1e-15) and x[t].sum() <= 1 + 1e-12
        free = (x[t] > lo + 1e-12) & (x[t] < hi - 1e-12)
        lam = float(np.mean((w[t] - x[t])[free])) if free.any() else max(0.0, float(np.min(w[t] - x[t])))
        assert lam >= -1e-12
        np.testing.assert_allclose(x[t], np.clip(w[t] - lam, lo, hi), atol=1e-10)
        if lam > 1e-10:
            assert x[t].sum() == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(fs.project_convex(x, lo, hi), x, atol=1e-14)  # idempotent


def test_projection_matches_slsqp():
    rng = np.random.default_rng(11)
    w = rng.uniform(0, 1, 7)
    x = fs.project_convex(w)
    ref = minimize(lambda z: 0.5 * np.sum((z - w) ** 2), np.zeros(7), jac=lambda z: z - w, method="SLSQP",
                   bounds=[(0, 1)] * 7, constraints=[{"type": "ineq", "fun": lambda z: 1 - z.sum()}],
                   options={"ftol": 1e-14, "maxiter": 500})
    np.testing.assert_allclose(x, ref.x, atol=1e-7)
    assert x.sum() == pytest.approx(1.0, abs=1e-14)


def test_projection_keeps_feasible_points_and_rejects_empty_set():
    w = np.array([0.2, 0.3, 0.1])
    np.testing.assert_array_equal(fs.project_convex(w), w)
    with pytest.raises(ShapeSpaceError, match="lo"):
        fs.project_convex(w, lo=0.5)
    with pytest.raises(ShapeSpaceError, match="w must have shape"):
        fs.project_convex(np.zeros((2, 2, 2)))


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


# -------------------------------------------------------------- diagnostics
def diagnostic_model():
    rng = np.random.default_rng(12)
    d = np.zeros((6, 8, 3))
    d[0] = rng.normal(size=(8, 3))
    d[1] = 2.5 * d[0]          # scaled duplicate
    d[2] = -d[0]               # negated
    d[3, :4] = rng.normal(size=(4, 3))
    d[4, 4:] = rng.normal(size=(4, 3))   # orthogonal to d[3] (disjoint support)
    d[5, 0, 0] = 1e-12         # empty
    d[3, :, :] += 0.0
    return BlendshapeModel(rng.normal(size=(8, 3)), d, ["a", "a2", "neg", "left", "right", "nothing"])


def test_coherence_of_duplicates_orthogonal_and_empty_targets():
    model = diagnostic_model()
    C = fs.coherence_matrix(model)
    assert C.shape == (6, 6)
    np.testing.assert_allclose(C[0, 1], 1.0)
    np.testing.assert_allclose(C[0, 2], 1.0)
    np.testing.assert_allclose(C[1, 2], 1.0)
    assert C[3, 4] == 0.0
    np.testing.assert_array_equal(C[5], 0.0)
    np.testing.assert_array_equal(C[:, 5], 0.0)
    np.testing.assert_array_equal(np.diag(C), [1, 1, 1, 1, 1, 0])
    np.testing.assert_allclose(C, C.T)
    assert fs.empty_targets(model) == ["nothing"]
    none = BlendshapeModel(np.zeros((2, 3)), np.zeros((0, 2, 3)), [])
    assert fs.coherence_matrix(none).shape == (0, 0) and fs.mutual_coherence(none) == 0.0
    assert fs.mutual_coherence(model) == pytest.approx(1.0)
    pairs = fs.similar_pairs(model, threshold=0.95)
    assert {(a, b) for a, b, _ in pairs} == {("a", "a2"), ("a", "neg"), ("a2", "neg")}
    assert all(c == pytest.approx(1.0) for _, _, c in pairs)
    coh = [c for *_, c in fs.similar_pairs(random_model(1, p=3, n=8), threshold=0.01)]
    assert coh == sorted(coh, reverse=True) and len(coh) > 3


def test_coherence_matches_definition_on_random_rig():
    model = random_model(3, p=10, n=5)
    flat = model.deltas.reshape(5, -1)
    ref = np.abs(flat @ flat.T) / np.outer(np.linalg.norm(flat, axis=1), np.linalg.norm(flat, axis=1))
    np.testing.assert_allclose(fs.coherence_matrix(model), ref, atol=1e-14)
    off = ref - np.diag(np.diag(ref))
    assert fs.mutual_coherence(model) == pytest.approx(off.max())


def test_coherence_image():
    C = fs.coherence_matrix(diagnostic_model())
    img = fs.coherence_image(C)
    assert img.dtype == np.uint8 and img.shape == (6 * 42, 6 * 42, 4)
    assert np.all(img[..., 3] == 255)
    cell = 42
    diag = img[cell // 2, cell // 2].astype(int)
    zero = img[3 * cell + cell // 2, 4 * cell + cell // 2].astype(int)
    assert diag[:3].sum() > zero[:3].sum() + 200  # 1 is bright, 0 dark
    assert fs.coherence_image(np.eye(3), size=30).shape == (30, 30, 4)
    assert fs.coherence_image(np.eye(100), size=50).shape == (100, 100, 4)  # at least 1 px per cell
    with pytest.raises(ShapeSpaceError, match="C must have shape"):
        fs.coherence_image(np.zeros((2, 3)))


# ------------------------------------------------------------------ sparsity
def test_one_active_target_per_frame_is_maximally_sparse():
    model = random_model(13, p=40, n=8)
    rng = np.random.default_rng(14)
    w = np.zeros((50, 8))
    w[np.arange(50), rng.integers(0, 8, 50)] = rng.uniform(0.2, 1.0, 50)
    res = fs.sparsity_comparison(model, w)
    bs, pc = res.value["blendshape"], res.value["pca"]
    assert bs["hoyer"] == pytest.approx(1.0)
    assert bs["count_95_energy"] == 1.0
    assert bs["small_fraction"] == pytest.approx(7 / 8)
    assert bs["hoyer_rms"] == pytest.approx(1.0)
    assert pc["hoyer"] < 0.9 and pc["hoyer_rms"] < 0.9 and pc["count_95_energy"] > 1.0
    assert bs["curve_small_fraction"] > 0.8 > pc["curve_small_fraction"]
    assert pc["n_coefficients"] == 8 and res.success


def test_sparsity_with_given_basis_and_dense_weights():
    model = random_model(15, p=20, n=5)
    w = np.full((4, 5), 0.5)
    w[0] = 0.0
    res = fs.sparsity_comparison(model, w, basis=fs.pca_from_model(model))
    bs = res.value["blendshape"]
    assert bs["hoyer"] == pytest.approx(0.0, abs=1e-12) and bs["zero_frames"] == 1
    assert bs["small_fraction"] == 0.0 and bs["curve_small_fraction"] == 0.25
    assert res.value["pca"]["n_coefficients"] == 5
    with pytest.raises(ShapeSpaceError, match="weights must have shape"):
        fs.sparsity_comparison(model, np.zeros(5))


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
