"""Target diagnostics (core.facespace.diagnostics, thesis 3.7.1, 3.7.6, Figs 3.12–3.15): empty targets,
coherence and near-duplicates against their definition, the coherence image, and sparsity."""
import numpy as np
import pytest

from core import facespace as fs
from core.blendshape import BlendshapeModel
from core.result import ShapeSpaceError
from facespace_models import random_model


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
