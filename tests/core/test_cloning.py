"""core.retarget.cloning: the channel mapping, copy with gain and offset, the linear expression cloning matrix, key
poses (thesis 3.5.3).

References are built here independently of the code under test: hand-made mappings, exact linear maps recovered
from enough pose pairs, principal axes of constructed data and an SVD.
"""
import numpy as np
import pytest

from core.result import ShapeSpaceError
from core.retarget import MAX_MAPPING_VALUE, cloning_matrix, copy_weights, key_poses, resolve_channel_mapping


def test_copy_weights_gain_offset():
    rng = np.random.default_rng(1)
    S = rng.uniform(0, 1, (7, 3))
    gain = np.array([2.0, 0.5, -1.0, 3.0])
    offset = np.array([0.1, 0.0, 0.25, -0.5])
    out = copy_weights(S, [(0, 2), (2, 0), (1, 3)], 4, gain=gain, offset=offset)
    assert out.shape == (7, 4)
    np.testing.assert_allclose(out[:, 2], -1.0 * S[:, 0] + 0.25, atol=1e-15)
    np.testing.assert_allclose(out[:, 0], 2.0 * S[:, 2] + 0.1, atol=1e-15)
    np.testing.assert_allclose(out[:, 3], 3.0 * S[:, 1] - 0.5, atol=1e-15)
    np.testing.assert_array_equal(out[:, 1], 0.0)                 # unmapped target channel stays 0


def test_copy_weights_plain_copy():
    S = np.array([[0.1, 0.2], [0.3, 0.4], [0.5, 0.6]])
    out = copy_weights(S, [(1, 0)], 3)
    np.testing.assert_array_equal(out, [[0.2, 0, 0], [0.4, 0, 0], [0.6, 0, 0]])


def test_copy_weights_clamping():
    S = np.array([[-0.5, 0.2], [0.5, 1.4], [1.5, 0.9]])
    lo, hi = np.array([0.0, 0.0]), np.array([1.0, 1.2])
    out = copy_weights(S, [(0, 0), (1, 1)], 2, gain=np.array([1.0, 1.0]), offset=np.array([0.0, 0.0]),
                       lo=lo, hi=hi)
    np.testing.assert_array_equal(out, [[0.0, 0.2], [0.5, 1.2], [1.0, 0.9]])
    only_hi = copy_weights(S, [(0, 0), (1, 1)], 2, hi=hi)
    np.testing.assert_array_equal(only_hi, [[-0.5, 0.2], [0.5, 1.2], [1.0, 0.9]])
    only_lo = copy_weights(S, [(0, 0), (1, 1)], 2, lo=lo)
    np.testing.assert_array_equal(only_lo, [[0.0, 0.2], [0.5, 1.4], [1.5, 0.9]])


@pytest.mark.parametrize("mapping", [[], ()])
def test_copy_weights_empty_mapping(mapping):
    with pytest.raises(ShapeSpaceError) as exc:
        copy_weights(np.zeros((3, 2)), mapping, 2)
    assert exc.value.code == "no_mapping"


@pytest.mark.parametrize("c, ns, nt", [(12, 5, 3), (5, 5, 4), (40, 8, 10)])
def test_cloning_matrix_exact_recovery(c, ns, nt):
    rng = np.random.default_rng(c * 100 + ns)
    Ws = rng.standard_normal((c, ns))
    E = rng.standard_normal((ns, nt))
    Wt = Ws @ E
    E_hat = cloning_matrix(Ws, Wt)
    assert E_hat.shape == (ns, nt)
    # The documented tiny ridge ε = 1e-8·tr(A)/n (A = WsᵀWs) biases the exact answer by
    # Ê − E = −ε (A + εI)⁻¹ E, so ‖Ê − E‖ ≤ ε/λ_min(A)·‖E‖ (bound computed here, not tuned).
    A = Ws.T @ Ws
    eps = 1e-8 * np.trace(A) / ns
    bound = eps / np.linalg.eigvalsh(A)[0] * np.linalg.norm(E, 2)
    assert np.linalg.norm(E_hat - E, 2) <= 1.01 * bound + 1e-12
    np.testing.assert_allclose(E_hat, E, rtol=0, atol=1e-6)


def test_cloning_matrix_least_squares_with_noise():
    rng = np.random.default_rng(3)
    Ws = rng.standard_normal((30, 4))
    Wt = Ws @ rng.standard_normal((4, 2)) + 0.1 * rng.standard_normal((30, 2))
    E_ls = np.linalg.lstsq(Ws, Wt, rcond=None)[0]
    np.testing.assert_allclose(cloning_matrix(Ws, Wt), E_ls, rtol=0, atol=1e-6)


def test_cloning_matrix_too_few_pairs():
    rng = np.random.default_rng(4)
    with pytest.raises(ShapeSpaceError) as exc:
        cloning_matrix(rng.standard_normal((4, 5)), rng.standard_normal((4, 3)))
    assert exc.value.code == "too_few"


def test_cloning_matrix_shape_mismatch():
    with pytest.raises(ShapeSpaceError) as exc:
        cloning_matrix(np.zeros((6, 3)), np.zeros((5, 2)))
    assert exc.value.code == "shape"


def test_key_poses_constructed_principal_axes():
    """Data built with known principal axes Q and orthonormal zero-mean scores Z: the key frames are the
    arg max / arg min of each score column (sign of a PC only swaps max and min)."""
    rng = np.random.default_rng(5)
    F, n = 60, 6
    raw = rng.standard_normal((F, n))
    Z, _ = np.linalg.qr(raw - raw.mean(axis=0))          # orthonormal, zero-mean columns
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    scales = np.array([10.0, 6.0, 3.0, 1.0, 0.5, 0.2])
    W = rng.uniform(0, 1, n) + (Z * scales) @ Q.T
    picks = key_poses(W, components=3)
    expected = []
    for j in range(3):
        for k in (int(np.argmax(Z[:, j])), int(np.argmin(Z[:, j]))):
            if k not in expected:
                expected.append(k)
    assert len(picks) == len(set(picks.tolist()))
    assert set(picks.tolist()) == set(expected)
    # PC by PC: the first two picks are the extremes of PC 1 in some order
    assert set(picks[:2].tolist()) == {int(np.argmax(Z[:, 0])), int(np.argmin(Z[:, 0]))}


@pytest.mark.parametrize("components", [1, 2, 4])
def test_key_poses_against_svd(components):
    rng = np.random.default_rng(6 + components)
    W = rng.uniform(0, 1, (80, 9)) @ np.diag(np.linspace(2, 0.2, 9))
    C = W - W.mean(axis=0)
    evals, evecs = np.linalg.eigh(C.T @ C)             # covariance eigenvectors, largest last
    P = C @ evecs[:, ::-1][:, :components]
    expected = {int(i) for j in range(components) for i in (np.argmax(P[:, j]), np.argmin(P[:, j]))}
    picks = key_poses(W, components=components)
    assert picks.dtype.kind == "i"
    assert set(picks.tolist()) == expected
    assert len(picks) == len(expected)


# --------------------------------------------------------------------------- the channel mapping
SOURCE = ["jawOpen", "eyeBlinkLeft", "mouthSmileLeft", "tongueOut"]
TARGET = ["JawOpen", "EyeBlink_L", "MouthSmile_L", "MouthClose"]


def test_channels_are_matched_by_name_without_overrides():
    mapping, warnings = resolve_channel_mapping({}, SOURCE, TARGET, "Face")
    assert mapping == [(0, 0, 1.0, 0.0), (1, 1, 1.0, 0.0), (2, 2, 1.0, 0.0)] and warnings == []


def test_overrides_win_and_claim_their_target():
    overrides = {"tongueOut": {"target": "JawOpen", "gain": 0.5, "offset": 0.1},
                 "mouthSmileLeft": {"target": "MouthClose"},                 # gain 1, offset 0
                 "notInTheSource": {"target": "EyeBlink_L", "gain": 2.0}}     # ignored
    mapping, warnings = resolve_channel_mapping(overrides, SOURCE, TARGET, "Face")
    # jawOpen loses JawOpen to the override of tongueOut; mouthSmileLeft goes where its override says
    assert mapping == [(1, 1, 1.0, 0.0), (2, 3, 1.0, 0.0), (3, 0, 0.5, 0.1)] and warnings == []


def test_a_stale_override_is_named_and_its_channel_matched_by_name():
    overrides = {"jawOpen": {"target": "Deleted", "gain": 2.0}, "tongueOut": {"target": "Gone"}}
    mapping, warnings = resolve_channel_mapping(overrides, SOURCE, TARGET, "Face")
    assert mapping == [(0, 0, 1.0, 0.0), (1, 1, 1.0, 0.0), (2, 2, 1.0, 0.0)]
    assert warnings == ["the channel mapping jawOpen → Deleted names no shape key of 'Face': jawOpen was matched "
                        "by name to JawOpen",
                        "the channel mapping tongueOut → Gone names no shape key of 'Face': tongueOut is not "
                        "retargeted (fix or remove the override)"]


@pytest.mark.parametrize("gain, offset", [(float("nan"), 0.0), (1.0, float("inf")), (MAX_MAPPING_VALUE * 1.01, 0.0)])
def test_a_non_finite_or_absurd_override_is_refused_naming_the_channel(gain, offset):
    with pytest.raises(ShapeSpaceError, match="the channel mapping of 'jawOpen' has a non-finite or out-of-range") \
            as err:
        resolve_channel_mapping({"jawOpen": {"target": "JawOpen", "gain": gain, "offset": offset}}, SOURCE, TARGET)
    assert err.value.code == "non_finite"


def test_no_shared_channel_is_refused():
    with pytest.raises(ShapeSpaceError, match="share no channels") as err:
        resolve_channel_mapping({}, ["foo", "bar"], TARGET)
    assert err.value.code == "no_mapping"
