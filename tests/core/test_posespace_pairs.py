"""Weighted PSD's bone-pair distance (#16 Build 5): relative rotations between a vertex's bones, checked against
Blender's pose-matrix formula written out here, and its effect on a corrective that depends on one bone turning
relative to its parent."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from core.errors import ErrorCode
from core.posespace.pairs import SINGLE_WEIGHT, bone_pairs, pair_metric
from core.posespace.psd import skin_group_inputs, train_psd
from core.posespace.readers import PoseReader, pose_features
from core.result import ShapeSpaceError

# root → upper → (lower, side): "lower" and "side" are siblings; "tip" (child of lower) is not in the pose space
NAMES = ["root", "upper", "lower", "side", "tip"]
PARENTS = [-1, 0, 1, 1, 2]
READ = ["upper", "lower", "side", "root"]          # reader order differs from bone order on purpose


def rest_matrices(rng):
    rest = np.tile(np.eye(4), (len(NAMES), 1, 1))
    for b in range(len(NAMES)):
        rest[b, :3, :3] = Rotation.random(random_state=rng.integers(1 << 30)).as_matrix()
        rest[b, :3, 3] = rng.normal(size=3)
    return rest


def blender_channels(rest, basis):
    """``pose · rest⁻¹`` per bone with Blender's rule ``pose = pose_parent · rest_parent⁻¹ · rest · basis``."""
    pose = np.empty_like(rest)
    for b, p in enumerate(PARENTS):
        pose[b] = rest[b] @ basis[b] if p < 0 else pose[p] @ np.linalg.inv(rest[p]) @ rest[b] @ basis[b]
    return pose @ np.linalg.inv(rest)


def skin(p=6):
    """Vertices skinned to (upper, lower), (lower, side), (lower, tip), (root only), (upper, side, lower)."""
    bi = np.array([[1, 2, -1], [2, 3, -1], [2, 4, -1], [0, -1, -1], [1, 3, 2], [3, -1, -1]])[:p]
    bw = np.array([[0.5, 0.5, 0], [0.7, 0.3, 0], [0.6, 0.4, 0], [1, 0, 0], [0.2, 0.3, 0.5], [1, 0, 0]])[:p]
    return bi, bw


def random_pose(rng, readers, angle=1.0):
    quats = [Rotation.from_rotvec(rng.normal(size=3) * angle / 2).as_quat(scalar_first=True) for _ in readers]
    return quats, pose_features(readers, quats)


def test_channels_and_relative_rotations_follow_blenders_pose_formula():
    rng = np.random.default_rng(0)
    rest = rest_matrices(rng)
    readers = [PoseReader("rotation", n, scale=s) for n, s in zip(READ, (1.0, 2.0, 0.5, 1.0))]
    bi, bw = skin()
    kw = skin_group_inputs(readers, NAMES, bi, bw)
    bp = bone_pairs(readers, NAMES, rest, PARENTS, kw["vertex_groups"], kw["vertex_weights"])
    read_bones = [READ[g] for g in bp.groups]
    assert read_bones[0] == "root"                                       # parents first
    pairs = {tuple(sorted((read_bones[a], read_bones[b]))) for a, b in bp.pairs}
    assert pairs == {("lower", "upper"), ("lower", "side"), ("side", "upper")}   # tip is not read; root alone
    for _ in range(5):
        quats, x = random_pose(rng, readers)
        basis = np.tile(np.eye(4), (len(NAMES), 1, 1))
        for n, q in zip(READ, quats):
            basis[NAMES.index(n), :3, :3] = Rotation.from_quat(q, scalar_first=True).as_matrix()
        want = blender_channels(rest, basis)[:, :3, :3]
        got = bp.channels(x[None])[0]
        for r, n in enumerate(read_bones):
            np.testing.assert_allclose(got[r], want[NAMES.index(n)], atol=1e-12)
        feats = bp.features(x[None])[0].reshape(-1, 3, 3)
        for k, (a, b) in enumerate(bp.pairs):
            ia, ib = NAMES.index(read_bones[a]), NAMES.index(read_bones[b])
            np.testing.assert_allclose(feats[k] * np.sqrt(2) + np.eye(3), want[ia].T @ want[ib], atol=1e-12)


def test_a_parent_turning_both_bones_changes_no_relative_rotation():
    """Turning 'upper' turns lower and side with it: no relative rotation of any pair changes (upper's own
    pairs are with its children, whose relative turn is their own local rotation).  Turning 'lower' changes
    its pairs and leaves (upper, side) alone."""
    rng = np.random.default_rng(1)
    rest = rest_matrices(rng)
    readers = [PoseReader("rotation", n) for n in READ]
    bi, bw = skin()
    kw = skin_group_inputs(readers, NAMES, bi, bw)
    bp = bone_pairs(readers, NAMES, rest, PARENTS, kw["vertex_groups"], kw["vertex_weights"])
    read_bones = [READ[g] for g in bp.groups]
    names = [frozenset((read_bones[a], read_bones[b])) for a, b in bp.pairs]
    quats, x = random_pose(rng, readers)

    def turned(bone):
        q = list(quats)
        q[READ.index(bone)] = Rotation.random(random_state=5).as_quat(scalar_first=True)
        return bp.features(pose_features(readers, q)[None])[0].reshape(-1, 9)
    base = bp.features(x[None])[0].reshape(-1, 9)
    np.testing.assert_allclose(turned("upper"), base, atol=1e-12)
    change = np.abs(turned("lower") - base).max(axis=1)
    for k, pair in enumerate(names):
        assert (change[k] > 0.1) == ("lower" in pair), pair
    assert bp.features(x[None]).shape == (1, 9 * len(names))


def test_pair_metric_weights_are_the_skin_products():
    rng = np.random.default_rng(2)
    readers = [PoseReader("rotation", n) for n in READ]
    bi, bw = skin()
    kw = skin_group_inputs(readers, NAMES, bi, bw)
    bp = bone_pairs(readers, NAMES, rest_matrices(rng), PARENTS, kw["vertex_groups"], kw["vertex_weights"])
    gi, gw = kw["vertex_groups"], kw["vertex_weights"] / kw["vertex_weights"].sum(1, keepdims=True)
    M = pair_metric(bp, gi, gw, len(READ)).toarray()
    read_bones = [READ[g] for g in bp.groups]
    col = {frozenset((read_bones[a], read_bones[b])): len(READ) + k for k, (a, b) in enumerate(bp.pairs)}
    # vertex 0: upper 0.5, lower 0.5 → singles ¼·0.25 each, the pair 0.25
    np.testing.assert_allclose(M[0, READ.index("upper")], SINGLE_WEIGHT * 0.25)
    np.testing.assert_allclose(M[0, col[frozenset(("upper", "lower"))]], 0.25)
    assert np.count_nonzero(M[0]) == 3
    # vertex 4: upper 0.2, side 0.3, lower 0.5 → three pairs
    np.testing.assert_allclose(M[4, col[frozenset(("upper", "side"))]], 0.06)
    np.testing.assert_allclose(M[4, col[frozenset(("side", "lower"))]], 0.15)
    np.testing.assert_allclose(M[4, col[frozenset(("upper", "lower"))]], 0.10)
    # vertex 3: root alone → its own rotation only
    np.testing.assert_allclose(M[3], np.eye(M.shape[1])[READ.index("root")] * SINGLE_WEIGHT)


def elbow_case(rng, K, n_test=60):
    """Vertices skinned half to 'upper', half to 'lower'; the corrective grows with lower's turn relative to
    upper (1 − cos θ: what a collapsing elbow needs), while 'upper' and 'root' swing freely."""
    rest = np.tile(np.eye(4), (len(NAMES), 1, 1))
    readers = [PoseReader("rotation", n) for n in ("root", "upper", "lower")]
    p = 30
    bi = np.tile([1, 2], (p, 1))
    bw = np.column_stack([np.linspace(0.3, 0.7, p), 1 - np.linspace(0.3, 0.7, p)])
    dirs = rng.normal(size=(p, 3))

    def draw(n):
        poses, D = [], []
        for _ in range(n):
            quats, x = random_pose(rng, readers, angle=1.2)
            theta = Rotation.from_quat(quats[2], scalar_first=True).magnitude()
            poses.append(x)
            D.append((1 - np.cos(theta)) * dirs * (bw[:, :1] * bw[:, 1:]) * 4)
        return np.array(poses), np.array(D)
    X, D = draw(K)
    Xt, Dt = draw(n_test)
    kw = skin_group_inputs(readers, NAMES, bi, bw)
    bp = bone_pairs(readers, NAMES, rest, PARENTS, kw["vertex_groups"], kw["vertex_weights"])
    return X, D, Xt, Dt, kw, bp


def held_out_error(model, Xt, Dt):
    return float(np.mean([np.abs(model.evaluate(x) - d).max() for x, d in zip(Xt, Dt)]))


def test_bone_pairs_beat_the_skin_weighted_distance_on_a_relative_turn():
    X, D, Xt, Dt, kw, bp = elbow_case(np.random.default_rng(4), K=16)
    skin_err = held_out_error(train_psd(X, D, "wpsd", **kw), Xt, Dt)
    pairs = train_psd(X, D, "wpsd", blend="pairs", pairs=bp, **kw)
    auto = train_psd(X, D, "wpsd", blend="auto", pairs=bp, **kw)
    assert held_out_error(pairs, Xt, Dt) <= 0.6 * skin_err
    assert auto.diagnostics["pair_regions"]                              # leave-one-out picks the pairs
    assert held_out_error(auto, Xt, Dt) <= 0.6 * skin_err
    for k in range(len(X)):                                              # still interpolates its examples
        np.testing.assert_allclose(pairs.evaluate(X[k]), D[k], atol=1e-9)


def test_fast_evaluation_of_the_bone_pair_distance_matches_float64():
    X, D, Xt, Dt, kw, bp = elbow_case(np.random.default_rng(6), K=12)
    for blend in ("pairs", "auto"):
        model = train_psd(X, D, "wpsd", blend=blend, pairs=bp, **kw)
        size = float(np.abs(D).max())
        model.prepare_fast(size=size)
        for x in Xt[:10]:
            assert np.abs(model.evaluate_fast(x) - model.evaluate(x)).max() <= 1e-6 * size


def test_pairs_needed_and_checked():
    X, D, Xt, Dt, kw, bp = elbow_case(np.random.default_rng(7), K=6)
    with pytest.raises(ShapeSpaceError, match="pairs") as e:
        train_psd(X, D, "wpsd", blend="pairs", **kw)
    assert e.value.code == ErrorCode.WPSD_INPUTS
    readers = [PoseReader("swing", "upper"), PoseReader("rotation", "lower")]   # one rotation-read bone: no pair
    kw1 = skin_group_inputs(readers, NAMES, np.tile([1, 2], (4, 1)), np.full((4, 2), 0.5))
    assert bone_pairs(readers, NAMES, np.tile(np.eye(4), (5, 1, 1)), PARENTS, kw1["vertex_groups"],
                      kw1["vertex_weights"]) is None
    with pytest.raises(ShapeSpaceError, match="rest"):
        bone_pairs(readers, NAMES, np.eye(4)[None], PARENTS, kw1["vertex_groups"], kw1["vertex_weights"])
    # without pairs, "auto" is the blended distance of before (no bone-pair term)
    model = train_psd(X, D, "wpsd", blend="auto", **kw)
    assert model.pairs is None and model.diagnostics["pair_regions"] == []
