"""Face-space core checks added by the hardening issue (#10): how many Neutral keys a whole-face rig needs
under a per-key weight limit, and stored face-prior arrays checked against each other."""
import numpy as np
import pytest

from core import facespace as fs
from core.result import ShapeSpaceError


@pytest.mark.parametrize("lo,hi,want", [
    (np.zeros(51), np.ones(51), 5),            # FBHead: 1 − Σw down to −50 → five shares of ≥ −10
    (np.zeros(10), np.ones(10), 1),            # 1 − Σw ∈ [−9, 1]
    (np.zeros(11), np.ones(11), 1),            # −10 exactly: still one key
    (np.zeros(12), np.ones(12), 2),
    (np.full(3, -10.0), np.full(3, 10.0), 4),  # 1 − Σw ∈ [−29, 31]
    (np.zeros(0), np.zeros(0), 1),
])
def test_neutral_key_count_keeps_every_share_within_the_limit(lo, hi, want):
    k = fs.neutral_key_count(lo, hi)
    assert k == want
    for w in (lo, hi):                               # the extremes of 1 − Σw over the slider box
        assert abs(1.0 - np.sum(w)) / k <= 10.0
    if k > 1:
        assert max(abs(1.0 - lo.sum()), abs(1.0 - hi.sum())) / (k - 1) > 10.0      # and no key to spare


def test_neutral_key_count_bad_input():
    with pytest.raises(ShapeSpaceError, match="slider_min must not exceed"):
        fs.neutral_key_count([1.0], [0.0])
    with pytest.raises(ShapeSpaceError, match="slider_max must have shape"):
        fs.neutral_key_count([0.0, 0.0], [1.0])
    with pytest.raises(ShapeSpaceError, match="limit must be positive"):
        fs.neutral_key_count([0.0], [1.0], limit=0.0)


def test_face_gaussian_from_arrays_round_trips_a_fit():
    W = np.random.default_rng(3).normal(size=(40, 5))
    g = fs.fit_face_gaussian(W)
    names = list("abcde")
    h = fs.face_gaussian_from_arrays(names, g.mean.tolist(), g.eigvecs.tolist(), g.eigvals.tolist(), g.dimension,
                                     g.ridge, g.regularised, g.message)
    np.testing.assert_allclose(h.whiten(W), g.whiten(W))


@pytest.mark.parametrize("change,match", [
    ({"names": ["a", "b", "c"]}, r"mean must have shape \(3,\), got \(5,\)"),
    ({"names": ["a", "a", "b", "c", "d"]}, "names repeats 'a'"),
    ({"names": "abcde"}, "names must be a non-empty list"),
    ({"mean": [0.0] * 4}, r"mean must have shape \(5,\)"),
    ({"mean": [None] * 5}, "mean contains NaN"),
    ({"eigvecs": np.eye(5)[:, :4]}, r"eigvecs must have shape \(5, 5\)"),
    ({"eigvecs": 2 * np.eye(5)}, "orthonormal"),
    ({"eigvals": np.zeros(5)}, "eigvals must be positive"),
    ({"dimension": 0.0}, "dimension must be positive"),
    ({"dimension": 9.0}, "at most the 5 sliders"),
    ({"ridge": -1.0}, "ridge must be ≥ 0"),
])
def test_face_gaussian_from_arrays_names_what_does_not_fit(change, match):
    args = dict(names=list("abcde"), mean=np.zeros(5), eigvecs=np.eye(5), eigvals=np.ones(5), dimension=5.0)
    args.update(change)
    with pytest.raises(ShapeSpaceError, match=match):
        fs.face_gaussian_from_arrays(**args)


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
