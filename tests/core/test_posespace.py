"""Pose-space readers (thesis 7.3, 8.1) against scipy.spatial.transform.Rotation and analytic identities."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from core.posespace.mirror import mirror_features, mirror_name, mirror_pose
from core.posespace.readers import (
    READER_DIMS,
    PoseReader,
    feature_groups,
    pose_features,
    quaternion_distance,
    quaternion_to_matrix,
    reader_features,
    swing_twist,
)
from core.result import ShapeSpaceError

Y = np.array([0.0, 1.0, 0.0])


# ------------------------------------------------------------------ helpers
def to_wxyz(rot):
    """scipy Rotation -> (w, x, y, z) quaternions (scipy stores scalar-last)."""
    q = np.atleast_2d(rot.as_quat())
    return np.concatenate([q[:, 3:], q[:, :3]], axis=1)


def to_rot(q_wxyz):
    q = np.atleast_2d(np.asarray(q_wxyz, float))
    return Rotation.from_quat(np.concatenate([q[:, 1:], q[:, :1]], axis=1))


def about(axis, angle):
    a = np.asarray(axis, float)
    return Rotation.from_rotvec(a / np.linalg.norm(a) * angle)


def random_rots(n, seed):
    return Rotation.random(n, random_state=seed)


@pytest.fixture
def rng():
    return np.random.default_rng(20240607)


# ------------------------------------------------------------------ quaternion_distance
def test_quaternion_distance_equals_relative_rotation_angle():
    r1, r2 = random_rots(200, 1), random_rots(200, 2)
    expected = (r1.inv() * r2).magnitude()
    # keep clear of 0 and pi, where 2*acos|q.p| only has sqrt(eps) precision
    ok = (expected > 1e-3) & (expected < np.pi - 1e-3)
    assert ok.sum() > 190
    got = quaternion_distance(to_wxyz(r1), to_wxyz(r2))
    assert got.shape == (200,)
    np.testing.assert_allclose(got[ok], expected[ok], rtol=0, atol=1e-9)


def test_quaternion_distance_single_pair_known_angle():
    q = to_wxyz(about([1, 2, 3], 0.3))[0]
    p = to_wxyz(about([1, 2, 3], 1.0))[0]
    assert quaternion_distance(q, p) == pytest.approx(0.7, abs=1e-12)


def test_quaternion_distance_symmetric_and_sign_invariant():
    a, b = to_wxyz(random_rots(50, 3)), to_wxyz(random_rots(50, 4))
    d = quaternion_distance(a, b)
    np.testing.assert_array_equal(d, quaternion_distance(b, a))
    np.testing.assert_allclose(quaternion_distance(-a, b), d, atol=1e-12)
    np.testing.assert_allclose(quaternion_distance(a, -b), d, atol=1e-12)
    np.testing.assert_allclose(quaternion_distance(-a, -b), d, atol=1e-12)
    # q and -q are the same rotation. 2*acos(x) near x=1 resolves only ~2*sqrt(2*eps) ~ 4e-8 rad.
    np.testing.assert_allclose(quaternion_distance(a, -a), 0.0, atol=1e-7)
    np.testing.assert_allclose(quaternion_distance(a, a), 0.0, atol=1e-7)


def test_quaternion_distance_normalises_inputs():
    a, b = to_wxyz(random_rots(10, 5)), to_wxyz(random_rots(10, 6))
    np.testing.assert_allclose(quaternion_distance(3.0 * a, 0.25 * b), quaternion_distance(a, b), atol=1e-12)


@pytest.mark.parametrize("bad, code", [
    ([0.0, 0.0, 0.0, 0.0], "non_finite"),
    ([np.nan, 0.0, 0.0, 1.0], "non_finite"),
    ([1.0, np.inf, 0.0, 0.0], "non_finite"),
    ([1.0, 0.0, 0.0], "shape"),
])
def test_quaternion_distance_bad_input(bad, code):
    good = [1.0, 0.0, 0.0, 0.0]
    for args in ((bad, good), (good, bad)):
        with pytest.raises(ShapeSpaceError) as e:
            quaternion_distance(*args)
        assert e.value.code == code


def test_zero_quaternion_in_a_batch_is_rejected():
    q = to_wxyz(random_rots(5, 7))
    q[3] = 0.0
    with pytest.raises(ShapeSpaceError):
        quaternion_distance(q, q)
    with pytest.raises(ShapeSpaceError):
        quaternion_to_matrix(q)


# ------------------------------------------------------------------ quaternion_to_matrix
def test_quaternion_to_matrix_matches_scipy():
    r = random_rots(100, 8)
    got = quaternion_to_matrix(to_wxyz(r))
    assert got.shape == (100, 3, 3)
    np.testing.assert_allclose(got, r.as_matrix(), atol=1e-12)


def test_quaternion_to_matrix_unnormalised_and_negated():
    r = random_rots(20, 9)
    q = to_wxyz(r) * np.linspace(0.1, 7.0, 20)[:, None]
    np.testing.assert_allclose(quaternion_to_matrix(q), r.as_matrix(), atol=1e-12)
    np.testing.assert_allclose(quaternion_to_matrix(-q), r.as_matrix(), atol=1e-12)


def test_quaternion_to_matrix_single_and_nested_batch():
    r = random_rots(6, 10)
    q = to_wxyz(r)
    np.testing.assert_allclose(quaternion_to_matrix(q[0]), r[0].as_matrix(), atol=1e-12)
    got = quaternion_to_matrix(q.reshape(2, 3, 4))
    assert got.shape == (2, 3, 3, 3)
    np.testing.assert_allclose(got.reshape(6, 3, 3), r.as_matrix(), atol=1e-12)
    # half-turn about z: (w, x, y, z) = (0, 0, 0, 1)
    np.testing.assert_allclose(quaternion_to_matrix([0, 0, 0, 1.0]), np.diag([-1.0, -1.0, 1.0]), atol=1e-15)


# ------------------------------------------------------------------ swing_twist
def twist_quat(tau):
    tau = np.asarray(tau, float)
    return np.stack([np.cos(tau / 2), np.zeros_like(tau), np.sin(tau / 2), np.zeros_like(tau)], -1)


def test_swing_twist_recomposes_q():
    r = random_rots(200, 11)
    q = to_wxyz(r)
    swing, tau = swing_twist(q)
    assert swing.shape == (200, 4) and tau.shape == (200,)
    recomposed = to_rot(swing) * to_rot(twist_quat(tau))
    np.testing.assert_allclose(recomposed.as_matrix(), r.as_matrix(), atol=1e-12)
    # as quaternions: equal up to sign
    rq = to_wxyz(recomposed)
    sign = np.sign(np.sum(rq * q, axis=1))[:, None]
    np.testing.assert_allclose(rq * sign, q, atol=1e-12)


def test_swing_has_no_y_component_and_moves_y_like_q():
    r = random_rots(200, 12)
    swing, _ = swing_twist(to_wxyz(r))
    np.testing.assert_allclose(np.linalg.norm(swing, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(swing[:, 2], 0.0, atol=1e-12)   # (w, x, y, z): no rotation about Y
    np.testing.assert_allclose(to_rot(swing).apply(Y), r.apply(Y), atol=1e-12)


def test_twist_is_a_rotation_about_y_by_the_returned_angle():
    # q = swing(axis ⟂ Y) * twist(Y): the decomposition must return exactly these parts
    rng = np.random.default_rng(13)
    for _ in range(50):
        phi = rng.uniform(0, 2 * np.pi)
        alpha = rng.uniform(-3.0, 3.0)
        tau = rng.uniform(-3.1, 3.1)
        sw = about([np.cos(phi), 0.0, np.sin(phi)], alpha)
        q = to_wxyz(sw * about(Y, tau))[0]
        swing, t = swing_twist(q)
        assert t == pytest.approx(tau, abs=1e-12)
        np.testing.assert_allclose(to_rot(swing).as_matrix()[0], sw.as_matrix(), atol=1e-12)


def test_twist_same_for_q_and_minus_q():
    q = to_wxyz(random_rots(200, 14))
    s1, t1 = swing_twist(q)
    s2, t2 = swing_twist(-q)
    np.testing.assert_allclose(t1, t2, atol=1e-12)
    np.testing.assert_allclose(to_rot(s1).as_matrix(), to_rot(s2).as_matrix(), atol=1e-12)


@pytest.mark.parametrize("angle", [-3.0, -1.2, -1e-3, 0.0, 0.4, 2.5, 3.1])
def test_pure_rotation_about_y_is_all_twist(angle):
    swing, tau = swing_twist(to_wxyz(about(Y, angle))[0])
    assert tau == pytest.approx(angle, abs=1e-12)
    np.testing.assert_allclose(np.abs(swing), [1.0, 0.0, 0.0, 0.0], atol=1e-12)


@pytest.mark.parametrize("angle", [-3.0, -0.5, 0.0, 0.7, 3.1, np.pi])
def test_pure_rotation_about_x_has_no_twist(angle):
    q = to_wxyz(about([1, 0, 0], angle))[0]
    swing, tau = swing_twist(q)
    assert tau == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(to_rot(swing).as_matrix()[0], about([1, 0, 0], angle).as_matrix(), atol=1e-12)


def test_swing_twist_custom_axis():
    axis = np.array([1.0, 2.0, -2.0]) / 3.0
    sw = about(np.cross(axis, [0.0, 0.0, 1.0]), 0.8)   # swing axis perpendicular to `axis`
    q = to_wxyz(sw * about(axis, -1.1))[0]
    swing, tau = swing_twist(q, axis=axis * 5.0)           # the axis need not be unit length
    assert tau == pytest.approx(-1.1, abs=1e-12)
    np.testing.assert_allclose(to_rot(swing).as_matrix()[0], sw.as_matrix(), atol=1e-12)
    np.testing.assert_allclose(swing[1:] @ axis, 0.0, atol=1e-12)


def test_twist_angle_within_pi():
    tau = swing_twist(to_wxyz(random_rots(500, 15)))[1]
    assert np.all(np.abs(tau) <= np.pi + 1e-15)


def test_half_turn_twist_is_minus_pi_as_documented():
    _, tau = swing_twist([0.0, 0.0, 1.0, 0.0])      # documented range [−π, π)
    assert tau == pytest.approx(-np.pi, abs=1e-12)


# ------------------------------------------------------------------ reader_features
def test_reader_dims_and_kinds():
    assert READER_DIMS == {"rotation": 9, "swing": 3, "twist": 2, "location": 3, "property": 1, "shape_key": 1}
    for kind, n in READER_DIMS.items():
        r = PoseReader(kind, "src")
        assert r.dims == n
        assert r.is_bone == (kind in ("rotation", "swing", "twist", "location"))


def test_rotation_features_are_scaled_matrix_minus_identity():
    r = random_rots(30, 16)
    f = reader_features(PoseReader("rotation", "arm"), to_wxyz(r))
    assert f.shape == (30, 9)
    np.testing.assert_allclose(f, (r.as_matrix() - np.eye(3)).reshape(30, 9) / np.sqrt(2.0), atol=1e-12)


def test_rotation_feature_distance_is_two_sin_half_angle():
    r1, r2 = random_rots(200, 17), random_rots(200, 18)
    reader = PoseReader("rotation", "arm")
    d = np.linalg.norm(reader_features(reader, to_wxyz(r1)) - reader_features(reader, to_wxyz(r2)), axis=1)
    theta = (r1.inv() * r2).magnitude()
    np.testing.assert_allclose(d, 2.0 * np.abs(np.sin(theta / 2.0)), atol=1e-12)
    # small angles read as radians
    q0 = to_wxyz(random_rots(1, 19))
    q1 = to_wxyz(random_rots(1, 19) * about([0.3, -1, 0.2], 1e-4))
    small = np.linalg.norm(reader_features(reader, q0) - reader_features(reader, q1))
    assert small == pytest.approx(1e-4, rel=1e-8)


def test_rotation_features_identify_q_and_minus_q():
    q = to_wxyz(random_rots(40, 20))
    reader = PoseReader("rotation", "arm")
    np.testing.assert_allclose(reader_features(reader, -q), reader_features(reader, q), atol=1e-12)
    np.testing.assert_allclose(reader_features(reader, [1.0, 0, 0, 0]), np.zeros(9), atol=1e-15)


def test_swing_features_are_where_y_points():
    r = random_rots(40, 21)
    f = reader_features(PoseReader("swing", "arm"), to_wxyz(r))
    assert f.shape == (40, 3)
    np.testing.assert_allclose(f, r.apply(Y) - Y, atol=1e-12)


def test_swing_features_ignore_roll_about_the_bone_axis():
    rng = np.random.default_rng(22)
    r = random_rots(100, 23)
    roll = Rotation.from_rotvec(np.outer(rng.uniform(-3, 3, 100), Y))
    reader = PoseReader("swing", "forearm")
    f0 = reader_features(reader, to_wxyz(r))
    f1 = reader_features(reader, to_wxyz(r * roll))            # local roll (twist applied first)
    np.testing.assert_allclose(f1, f0, atol=1e-12)
    # and a swing does change them
    f2 = reader_features(reader, to_wxyz(r * about([1, 0, 0], 0.5)))
    assert np.all(np.linalg.norm(f2 - f0, axis=1) > 1e-3)


def test_twist_features_ignore_swing_without_roll():
    rng = np.random.default_rng(24)
    reader = PoseReader("twist", "forearm")
    for _ in range(30):
        tau = rng.uniform(-3, 3)
        alpha = rng.uniform(-2.5, 2.5)
        base = reader_features(reader, to_wxyz(about(Y, tau))[0])
        np.testing.assert_allclose(base, [np.cos(tau) - 1.0, np.sin(tau)], atol=1e-12)
        swung = reader_features(reader, to_wxyz(about([1, 0, 0], alpha) * about(Y, tau))[0])
        np.testing.assert_allclose(swung, base, atol=1e-12)
    # twist features are the same for q and -q
    q = to_wxyz(random_rots(50, 25))
    np.testing.assert_allclose(reader_features(reader, -q), reader_features(reader, q), atol=1e-12)


def test_twist_feature_distance_is_chord_of_roll_angle():
    reader = PoseReader("twist", "forearm")
    a, b = 0.3, 1.9
    d = np.linalg.norm(reader_features(reader, to_wxyz(about(Y, a))[0])
                       - reader_features(reader, to_wxyz(about(Y, b))[0]))
    assert d == pytest.approx(2 * abs(np.sin((b - a) / 2)), abs=1e-12)


@pytest.mark.parametrize("kind, value", [
    ("rotation", [0.9, 0.1, -0.3, 0.2]),
    ("swing", [0.9, 0.1, -0.3, 0.2]),
    ("twist", [0.9, 0.1, -0.3, 0.2]),
    ("location", [0.5, -1.0, 2.0]),
    ("property", 0.7),
    ("shape_key", 0.25),
])
def test_scale_multiplies_features(kind, value):
    f1 = reader_features(PoseReader(kind, "s"), value)
    f3 = reader_features(PoseReader(kind, "s", scale=2.5), value)
    assert f1.shape == (READER_DIMS[kind],)
    np.testing.assert_allclose(f3, 2.5 * f1, rtol=1e-15, atol=0)
    assert np.any(f1 != 0)


def test_location_property_shape_key_shapes_and_values():
    loc = PoseReader("location", "hand")
    np.testing.assert_array_equal(reader_features(loc, [1.0, 2.0, 3.0]), [1.0, 2.0, 3.0])
    batch = np.arange(12.0).reshape(4, 3)
    np.testing.assert_array_equal(reader_features(loc, batch), batch)
    for kind in ("property", "shape_key"):
        r = PoseReader(kind, "exertion")
        assert reader_features(r, 0.4).shape == (1,)
        np.testing.assert_array_equal(reader_features(r, 0.4), [0.4])
        out = reader_features(r, [0.1, 0.2, 0.3])
        assert out.shape == (3, 1)
        np.testing.assert_array_equal(out[:, 0], [0.1, 0.2, 0.3])


@pytest.mark.parametrize("kind, value, code", [
    ("location", [1.0, 2.0], "shape"),
    ("location", [1.0, np.nan, 0.0], "non_finite"),
    ("property", np.inf, "non_finite"),
    ("shape_key", np.nan, "non_finite"),
    ("rotation", [np.nan, 0, 0, 1], "non_finite"),
    ("swing", [0, 0, 0, 0], "non_finite"),
    ("twist", [1, 0, 0], "shape"),
])
def test_reader_features_bad_values(kind, value, code):
    with pytest.raises(ShapeSpaceError) as e:
        reader_features(PoseReader(kind, "s"), value)
    assert e.value.code == code


# ------------------------------------------------------------------ PoseReader / pose_features
@pytest.mark.parametrize("kwargs, code", [
    (dict(kind="euler", source="arm"), "reader"),
    (dict(kind="rotation", source="arm", scale=0.0), "range"),
    (dict(kind="rotation", source="arm", scale=-1.0), "range"),
    (dict(kind="location", source="arm", scale=float("nan")), "range"),
])
def test_pose_reader_validation(kwargs, code):
    with pytest.raises(ShapeSpaceError) as e:
        PoseReader(**kwargs)
    assert e.value.code == code


def readers_and_values():
    q_arm = to_wxyz(about([0.2, 0.5, -1.0], 0.9))[0]
    q_fore = to_wxyz(about([1.0, 0.3, 0.0], -0.4))[0]
    readers = [PoseReader("rotation", "arm"), PoseReader("swing", "forearm", scale=2.0),
               PoseReader("twist", "forearm"), PoseReader("location", "hand", scale=0.5),
               PoseReader("property", "exertion"), PoseReader("shape_key", "smile", scale=3.0)]
    values = [q_arm, q_fore, q_fore, [1.0, -2.0, 0.5], 0.8, 0.1]
    return readers, values


def test_pose_features_concatenates_readers_in_order():
    readers, values = readers_and_values()
    f = pose_features(readers, values)
    assert f.shape == (9 + 3 + 2 + 3 + 1 + 1,)
    R_arm = to_rot(values[0]).as_matrix()[0]
    R_fore = to_rot(values[1])
    tau = swing_twist(values[2])[1]
    expected = np.concatenate([
        ((R_arm - np.eye(3)) / np.sqrt(2.0)).ravel(),
        2.0 * (R_fore.apply(Y)[0] - Y),
        [np.cos(tau) - 1.0, np.sin(tau)],
        0.5 * np.array([1.0, -2.0, 0.5]),
        [0.8],
        [0.3],
    ])
    np.testing.assert_allclose(f, expected, atol=1e-12)


def test_pose_features_batched():
    readers = [PoseReader("rotation", "a"), PoseReader("property", "p"), PoseReader("location", "b")]
    r = random_rots(5, 26)
    props = np.linspace(0, 1, 5)
    locs = np.arange(15.0).reshape(5, 3)
    f = pose_features(readers, [to_wxyz(r), props, locs])
    assert f.shape == (5, 13)
    for i in range(5):
        np.testing.assert_allclose(f[i], pose_features(readers, [to_wxyz(r[i])[0], props[i], locs[i]]),
                                   atol=1e-15)


def test_pose_features_errors():
    readers, values = readers_and_values()
    with pytest.raises(ShapeSpaceError) as e:
        pose_features(readers, values[:-1])
    assert e.value.code == "shape"
    with pytest.raises(ShapeSpaceError) as e:
        pose_features(readers[:2], values)
    assert e.value.code == "shape"
    with pytest.raises(ShapeSpaceError) as e:
        pose_features([], [])
    assert e.value.code == "no_readers"
    bad = list(values)
    bad[4] = float("nan")
    with pytest.raises(ShapeSpaceError) as e:
        pose_features(readers, bad)
    assert e.value.code == "non_finite"
    bad = list(values)
    bad[0] = [0.0, 0.0, 0.0, 0.0]
    with pytest.raises(ShapeSpaceError) as e:
        pose_features(readers, bad)
    assert e.value.code == "non_finite"


def test_feature_groups_columns():
    readers, values = readers_and_values()
    groups = feature_groups(readers)
    assert list(groups) == ["arm", "forearm", "hand", "exertion", "smile"]
    np.testing.assert_array_equal(groups["arm"], np.arange(0, 9))
    np.testing.assert_array_equal(groups["forearm"], np.arange(9, 14))     # swing 9..11 + twist 12..13
    np.testing.assert_array_equal(groups["hand"], [14, 15, 16])
    np.testing.assert_array_equal(groups["exertion"], [17])
    np.testing.assert_array_equal(groups["smile"], [18])
    f = pose_features(readers, values)
    all_cols = np.sort(np.concatenate(list(groups.values())))
    np.testing.assert_array_equal(all_cols, np.arange(f.shape[0]))


def test_feature_groups_non_adjacent_same_source():
    readers = [PoseReader("swing", "arm"), PoseReader("property", "p"), PoseReader("twist", "arm")]
    groups = feature_groups(readers)
    np.testing.assert_array_equal(groups["arm"], [0, 1, 2, 4, 5])
    np.testing.assert_array_equal(groups["p"], [3])


# ------------------------------------------------------------------ mirroring (X mirror, Blender's flipped pose)
MX = np.diag([-1.0, 1.0, 1.0])


def flip_quat(q):
    """Blender's flipped pose of a local quaternion: (w, x, -y, -z)."""
    return np.asarray(q, float) * np.array([1.0, 1.0, -1.0, -1.0])


def test_flipped_quaternion_is_the_reflected_rotation():
    r = random_rots(20, 30)
    np.testing.assert_allclose(to_rot(flip_quat(to_wxyz(r))).as_matrix(), MX @ r.as_matrix() @ MX, atol=1e-12)


@pytest.mark.parametrize("name, mirrored", [
    ("hand.L", "hand.R"), ("hand.R", "hand.L"), ("arm_L", "arm_R"), ("foot.l", "foot.r"), ("toe_r", "toe_l"),
    ("LeftArm", "RightArm"), ("RightUpLeg", "LeftUpLeg"), ("L_eye", "R_eye"), ("r_ear", "l_ear"),
    ("mixamorig:LeftHand", "mixamorig:RightHand"), ("brow_left", "brow_right"), ("spine", "spine"),
    ("exertion", "exertion"),
])
def test_mirror_name(name, mirrored):
    assert mirror_name(name) == mirrored
    assert mirror_name(mirrored) == name


@pytest.mark.parametrize("kind", ["rotation", "swing", "twist"])
@pytest.mark.parametrize("scale", [1.0, 2.5])
def test_mirror_features_of_bone_rotations(kind, scale):
    reader = PoseReader(kind, "arm.L", scale=scale)
    for q in to_wxyz(random_rots(25, 31)):
        got = mirror_features(reader, reader_features(reader, q))
        np.testing.assert_allclose(got, reader_features(reader, flip_quat(q)), atol=1e-12)
    R = random_rots(1, 32).as_matrix()[0]
    q = to_wxyz(Rotation.from_matrix(R))[0]
    Rm = MX @ R @ MX
    if kind == "rotation":
        ref = (Rm - np.eye(3)).ravel() / np.sqrt(2.0)
    elif kind == "swing":
        ref = Rm @ Y - Y
    else:
        tau = swing_twist(q)[1]
        ref = np.array([np.cos(-tau) - 1.0, np.sin(-tau)])      # a roll about Y reverses in the mirror
    np.testing.assert_allclose(mirror_features(reader, reader_features(reader, q)), scale * ref, atol=1e-12)


def test_mirror_features_location_and_scalars():
    loc = PoseReader("location", "hand.L", scale=0.5)
    np.testing.assert_allclose(mirror_features(loc, reader_features(loc, [1.0, 2.0, -3.0])),
                               0.5 * np.array([-1.0, 2.0, -3.0]), atol=1e-15)
    for kind in ("property", "shape_key"):
        r = PoseReader(kind, "exertion", scale=2.0)
        np.testing.assert_allclose(mirror_features(r, reader_features(r, 0.3)), [0.6], atol=1e-15)


def mirror_setup():
    readers = [PoseReader("rotation", "arm.L"), PoseReader("rotation", "arm.R"),
               PoseReader("twist", "forearm.L", scale=2.0), PoseReader("twist", "forearm.R", scale=2.0),
               PoseReader("location", "LeftHand"), PoseReader("location", "RightHand"),
               PoseReader("property", "exertion"), PoseReader("swing", "spine")]
    q = to_wxyz(random_rots(5, 33))
    values = [q[0], q[1], q[2], q[3], [0.1, 0.2, 0.3], [-0.4, 0.5, 0.6], 0.7, q[4]]
    return readers, values


def test_mirror_pose_swaps_sides_and_flips():
    readers, v = mirror_setup()
    mirrored_values = [flip_quat(v[1]), flip_quat(v[0]), flip_quat(v[3]), flip_quat(v[2]),
                       [0.4, 0.5, 0.6], [-0.1, 0.2, 0.3], 0.7, flip_quat(v[7])]
    pose = pose_features(readers, v)
    np.testing.assert_allclose(mirror_pose(readers, pose), pose_features(readers, mirrored_values), atol=1e-12)
    # mirroring twice gives the pose back
    np.testing.assert_allclose(mirror_pose(readers, mirror_pose(readers, pose)), pose, atol=1e-12)


def test_mirror_pose_without_counterpart():
    readers = [PoseReader("rotation", "arm.L"), PoseReader("swing", "arm.R")]    # same bone pair, other kind
    pose = pose_features(readers, [[1.0, 0, 0, 0], [1.0, 0, 0, 0]])
    with pytest.raises(ShapeSpaceError) as e:
        mirror_pose(readers, pose)
    assert e.value.code == "no_mirror"


# ------------------------------------------------------------------ mirrored correctives
def symmetric_mesh(rng, half=40):
    """A point set symmetric across x = 0 (plus points on the plane), in shuffled order."""
    left = rng.uniform(0.1, 1.0, size=(half, 3))
    mid = np.column_stack([np.zeros(5), rng.uniform(-1, 1, size=(5, 2))])
    co = np.vstack([left, left * [-1.0, 1.0, 1.0], mid])
    return co[rng.permutation(len(co))]


def test_mirror_partners_pair_each_vertex_with_its_reflection():
    from core.posespace.mirror import mirror_displacements, mirror_partners
    rng = np.random.default_rng(40)
    co = symmetric_mesh(rng)
    partner = mirror_partners(co)
    assert sorted(partner) == list(range(len(co)))                       # a permutation
    np.testing.assert_allclose(co[partner], co * [-1.0, 1.0, 1.0], atol=1e-12)
    np.testing.assert_array_equal(partner[partner], np.arange(len(co)))  # an involution
    delta = rng.normal(size=co.shape)
    mirrored = mirror_displacements(delta, partner)
    for v in range(len(co)):
        np.testing.assert_allclose(mirrored[v], delta[partner[v]] * [-1.0, 1.0, 1.0], atol=0)
    np.testing.assert_allclose(mirror_displacements(mirrored, partner), delta, atol=0)   # twice: back


def test_mirror_partners_refuse_an_asymmetric_mesh_within_tolerance():
    from core.posespace.mirror import mirror_displacements, mirror_partners
    rng = np.random.default_rng(41)
    co = symmetric_mesh(rng)
    off = int(np.flatnonzero(co[:, 0] > 0.05)[0])
    co[off] += [0.0, 0.01, 0.0]                      # nearly symmetric: one vertex off by ~0.3 % of the size
    with pytest.raises(ShapeSpaceError, match="not symmetric") as e:
        mirror_partners(co)
    assert e.value.code == "not_symmetric"
    assert mirror_partners(co, tolerance=0.01).shape == (len(co),)
    with pytest.raises(ShapeSpaceError) as e:
        mirror_displacements(np.zeros((4, 3)), np.arange(3))
    assert e.value.code == "shape"


def test_readers_name_themselves_when_refusing_a_scale_or_rotation():
    """Issue #10: a NaN reader scale or bone rotation is refused naming the reader."""
    with pytest.raises(ShapeSpaceError, match="rotation 'arm.L'.*got nan") as e:
        PoseReader("rotation", "arm.L", scale=float("nan"))
    assert e.value.code == "range"
    with pytest.raises(ShapeSpaceError, match="twist 'arm.L'.*positive") as e:
        PoseReader("twist", "arm.L", scale=0.0)
    assert e.value.code == "range"
    with pytest.raises(ShapeSpaceError, match="swing reader 'forearm.R'") as e:
        reader_features(PoseReader("swing", "forearm.R"), [np.nan, 0.0, 0.0, 1.0])
    assert e.value.code == "non_finite"
