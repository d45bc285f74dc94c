"""Linear-blend and dual-quaternion skinning against independent references."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from core.result import ShapeSpaceError
from core.skinning import (
    ArmatureDeform,
    SkinningRig,
    SkinWeights,
    deform,
    diagnose_weights,
    dual_quaternion_skinning,
    linear_blend_skinning,
    matrix_to_quaternion,
    normalised_weights,
)

ATOL = 1e-10


# ------------------------------------------------------------------ helpers
def rot_axis_angle(axis, angle):
    """3x3 rotation by Rodrigues' formula (independent of the code under test)."""
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def mat4(r=None, t=(0, 0, 0)):
    m = np.eye(4)
    m[:3, :3] = np.eye(3) if r is None else r
    m[:3, 3] = t
    return m


def rotation_about_point(axis, angle, point):
    """4x4 rotation about the line through ``point`` with direction ``axis``."""
    c = np.asarray(point, float)
    return mat4(t=c) @ mat4(rot_axis_angle(axis, angle)) @ mat4(t=-c)


def random_rigid(rng, tscale=1.0):
    r = Rotation.random(random_state=int(rng.integers(1 << 31))).as_matrix()
    return mat4(r, rng.normal(size=3) * tscale)


def random_affine(rng):
    """Rigid transform with a (non-uniform) positive scale: object world matrices."""
    r = Rotation.random(random_state=int(rng.integers(1 << 31))).as_matrix()
    return mat4(r @ np.diag(rng.uniform(0.5, 2.0, size=3)), rng.normal(size=3) * 3)


def apply(m, pts):
    return pts @ m[:3, :3].T + m[:3, 3]


def make_rig(weights, rest, mesh_world=None, arm_world=None, dqs=False, mask=None):
    mesh_world = np.eye(4) if mesh_world is None else mesh_world
    arm_world = np.eye(4) if arm_world is None else arm_world
    d = ArmatureDeform(weights, [f"b{i}" for i in range(len(rest))], rest, arm_world,
                       preserve_volume=dqs, vertex_mask=mask)
    return SkinningRig(mesh_world, [d])


def reference_lbs(coords, dense_w, mats, mask=None):
    """v + sum_i w_i (M_i v - v) / sum_i w_i, vertex by vertex, Blender's 1e-4 cut-off."""
    out = coords.copy()
    for p, v in enumerate(coords):
        tot = dense_w[p].sum()
        if tot <= 1e-4:
            continue
        disp = np.zeros(3)
        for i, m in enumerate(mats):
            if dense_w[p, i]:
                disp += dense_w[p, i] * (m[:3, :3] @ v + m[:3, 3] - v)
        out[p] = v + disp / tot * (1.0 if mask is None else mask[p])
    return out


def object_space_matrix(pose, rest, mesh_world, arm_world):
    P = np.linalg.inv(arm_world) @ mesh_world
    return np.linalg.inv(P) @ pose @ np.linalg.inv(rest) @ P


def dist_to_axis(pts, axis, point):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    d = pts - point
    return np.linalg.norm(d - np.outer(d @ a, a), axis=1)


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


# ---------------------------------------------------------------- identity
@pytest.mark.parametrize("dqs", [False, True])
def test_rest_pose_leaves_mesh_unchanged(rng, dqs):
    p, b = 25, 4
    coords = rng.normal(size=(p, 3))
    rest = np.stack([random_rigid(rng) for _ in range(b)])
    idx = rng.integers(-1, b, size=(p, 3))
    w = rng.uniform(0, 1, size=(p, 3))
    rig = make_rig(SkinWeights(idx, w), rest, random_affine(rng), random_affine(rng), dqs=dqs)
    np.testing.assert_allclose(deform(coords, rig, [rest.copy()]), coords, atol=ATOL)


@pytest.mark.parametrize("dqs", [False, True])
def test_identity_change_matrices_direct_calls(rng, dqs):
    coords = rng.normal(size=(10, 3))
    sw = SkinWeights(rng.integers(0, 3, size=(10, 2)), rng.uniform(0.1, 1, size=(10, 2)))
    eye = np.broadcast_to(np.eye(4), (3, 4, 4)).copy()
    if dqs:
        out = dual_quaternion_skinning(coords, sw, eye, eye, np.eye(4))
    else:
        out = linear_blend_skinning(coords, sw, eye)
    np.testing.assert_allclose(out, coords, atol=ATOL)


# -------------------------------------------------------------- single bone
@pytest.mark.parametrize("worlds", [False, True])
def test_single_rigid_bone_lbs_equals_dqs_equals_matrix(rng, worlds):
    p = 20
    coords = rng.normal(size=(p, 3)) * 2
    rest = random_rigid(rng)[None]
    pose = random_rigid(rng, tscale=3.0)[None]
    mw = random_affine(rng) if worlds else np.eye(4)
    aw = random_affine(rng) if worlds else np.eye(4)
    sw = SkinWeights(np.zeros((p, 1), int), np.ones((p, 1)))
    M = object_space_matrix(pose[0], rest[0], mw, aw)
    expected = apply(M, coords)
    lbs = deform(coords, make_rig(sw, rest, mw, aw, dqs=False), [pose])
    dqs = deform(coords, make_rig(sw, rest, mw, aw, dqs=True), [pose])
    np.testing.assert_allclose(lbs, expected, atol=1e-9)
    np.testing.assert_allclose(dqs, expected, atol=1e-9)


def _unit_column_shear(a=0.6):
    """Shear whose columns have unit length: not a rotation although every axis keeps its length."""
    A = np.array([[1.0, a, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    return mat4(A / np.linalg.norm(A, axis=0))


@pytest.mark.parametrize("scale", [0.5, 1.7, (1.0, 2.0, 0.5), "shear"])
def test_dqs_single_bone_with_scale_equals_full_matrix(rng, scale):
    p = 15
    coords = rng.normal(size=(p, 3))
    rest = random_rigid(rng)[None]
    # pose = rigid * scale in the bone's own frame (what an animator's bone scale gives)
    S = _unit_column_shear() if scale == "shear" else np.diag(list(np.broadcast_to(scale, 3)) + [1.0])
    pose = (random_rigid(rng) @ S)[None]
    sw = SkinWeights(np.zeros((p, 1), int), np.ones((p, 1)))
    mw, aw = random_affine(rng), random_rigid(rng)
    M = object_space_matrix(pose[0], rest[0], mw, aw)
    dqs = deform(coords, make_rig(sw, rest, mw, aw, dqs=True), [pose])
    lbs = deform(coords, make_rig(sw, rest, mw, aw, dqs=False), [pose])
    np.testing.assert_allclose(dqs, apply(M, coords), atol=1e-9)
    np.testing.assert_allclose(lbs, apply(M, coords), atol=1e-9)


def test_dqs_bones_sharing_rigid_motion_but_scaled_differently_equal_lbs(rng):
    # C_i = G @ rest @ S_i @ rest^-1: same rigid part G, different (non-uniform) scales.
    # Then LBS = G(sum w_i S'_i v) and DQS (either Blender scheme: blended scale matrix or
    # per-vertex pivot) = G(v + sum w_i (S'_i v - v)) -- the same point.
    p = 25
    coords = rng.normal(size=(p, 3))
    rest1 = random_rigid(rng)
    rest = np.stack([rest1, rest1])
    G = random_rigid(rng, 2.0)
    pose = np.stack([G @ rest1 @ np.diag([1.5, 1.0, 0.7, 1.0]), G @ rest1 @ np.diag([0.8, 1.2, 1.0, 1.0])])
    sw = SkinWeights(np.tile([0, 1], (p, 1)), rng.uniform(0.1, 1.0, size=(p, 2)))
    mw, aw = random_affine(rng), random_rigid(rng)
    dqs = deform(coords, make_rig(sw, rest, mw, aw, dqs=True), [pose])
    mats = [object_space_matrix(pose[i], rest[i], mw, aw) for i in range(2)]
    np.testing.assert_allclose(dqs, reference_lbs(coords, sw.weight, mats), atol=1e-9)


def test_dqs_mixed_scaled_and_rigid_bone_same_rigid_motion(rng):
    # one bone scaled, one not, same rigid part: result is G(v + w_s (S v - v) / sum w)
    p = 10
    coords = rng.normal(size=(p, 3))
    rest1 = random_rigid(rng)
    G = random_rigid(rng)
    pose = np.stack([G @ rest1 @ np.diag([2.0, 2.0, 2.0, 1.0]), G @ rest1])
    w = rng.uniform(0.1, 1.0, size=(p, 2))
    sw = SkinWeights(np.tile([0, 1], (p, 1)), w)
    dqs = deform(coords, make_rig(sw, np.stack([rest1, rest1]), dqs=True), [pose])
    Sfull = rest1 @ np.diag([2.0, 2.0, 2.0, 1.0]) @ np.linalg.inv(rest1)
    blended = coords + (w[:, :1] / w.sum(1, keepdims=True)) * (apply(Sfull, coords) - coords)
    np.testing.assert_allclose(dqs, apply(G, blended), atol=1e-9)


# --------------------------------------------------------------------- LBS
def test_two_bone_lbs_with_world_matrices_matches_dense_formula(rng):
    p, b = 40, 2
    coords = rng.normal(size=(p, 3))
    rest = np.stack([random_rigid(rng) for _ in range(b)])
    pose = np.stack([random_rigid(rng) for _ in range(b)])
    mw, aw = random_affine(rng), random_affine(rng)
    idx = np.tile([0, 1], (p, 1))
    w = rng.uniform(0.05, 1.0, size=(p, 2))
    out = deform(coords, make_rig(SkinWeights(idx, w), rest, mw, aw), [pose])
    mats = [object_space_matrix(pose[i], rest[i], mw, aw) for i in range(b)]
    np.testing.assert_allclose(out, reference_lbs(coords, w, mats), atol=1e-9)


def test_lbs_many_bones_sparse_influences(rng):
    p, b, k = 30, 5, 3
    coords = rng.normal(size=(p, 3))
    rest = np.stack([random_rigid(rng) for _ in range(b)])
    pose = np.stack([random_rigid(rng) for _ in range(b)])
    idx = rng.integers(-1, b, size=(p, k))
    w = rng.uniform(0, 1, size=(p, k))
    mw, aw = random_affine(rng), random_affine(rng)
    dense = np.zeros((p, b))
    for v in range(p):
        for j in range(k):
            if idx[v, j] >= 0:
                dense[v, idx[v, j]] += w[v, j]
    np.testing.assert_array_equal(SkinWeights(idx, w).dense(b), dense)
    out = deform(coords, make_rig(SkinWeights(idx, w), rest, mw, aw), [pose])
    mats = [object_space_matrix(pose[i], rest[i], mw, aw) for i in range(b)]
    np.testing.assert_allclose(out, reference_lbs(coords, dense, mats), atol=1e-9)


@pytest.mark.parametrize("dqs", [False, True])
def test_weight_normalisation(rng, dqs):
    p = 12
    coords = rng.normal(size=(p, 3))
    rest = np.stack([random_rigid(rng) for _ in range(2)])
    pose = np.stack([random_rigid(rng) for _ in range(2)])
    idx = np.tile([0, 1], (p, 1))
    a = deform(coords, make_rig(SkinWeights(idx, np.full((p, 2), 0.2)), rest, dqs=dqs), [pose])
    b = deform(coords, make_rig(SkinWeights(idx, np.full((p, 2), 0.5)), rest, dqs=dqs), [pose])
    c = deform(coords, make_rig(SkinWeights(idx, np.full((p, 2), 3.0)), rest, dqs=dqs), [pose])
    np.testing.assert_allclose(a, b, atol=ATOL)
    np.testing.assert_allclose(c, b, atol=ATOL)
    assert np.abs(b - coords).max() > 0.1  # the pose really moves the mesh


@pytest.mark.parametrize("dqs", [False, True])
def test_tiny_total_weight_does_not_move_but_small_weight_is_normalised(rng, dqs):
    coords = rng.normal(size=(4, 3))
    rest = random_rigid(rng)[None]
    pose = random_rigid(rng, 2.0)[None]
    idx = np.array([[0, 0], [0, 0], [0, -1], [0, 0]])
    w = np.array([[5e-5, 5e-5],   # total exactly 1e-4: Blender leaves it
                  [0.0, 0.0],     # unweighted
                  [2e-4, 0.0],    # small but above the cut-off: full motion after normalising
                  [0.5, 0.5]])
    out = deform(coords, make_rig(SkinWeights(idx, w), rest, dqs=dqs), [pose])
    M = pose[0] @ np.linalg.inv(rest[0])
    np.testing.assert_allclose(out[0], coords[0], rtol=0, atol=ATOL)
    np.testing.assert_allclose(out[1], coords[1], atol=ATOL)
    np.testing.assert_allclose(out[2:], apply(M, coords[2:]), atol=1e-9)


@pytest.mark.parametrize("dqs", [False, True])
def test_padding_index_is_ignored(rng, dqs):
    p = 10
    coords = rng.normal(size=(p, 3))
    rest = np.stack([random_rigid(rng) for _ in range(2)])
    pose = np.stack([random_rigid(rng) for _ in range(2)])
    w2 = rng.uniform(0.1, 1, size=(p, 2))
    plain = deform(coords, make_rig(SkinWeights(np.tile([0, 1], (p, 1)), w2), rest, dqs=dqs), [pose])
    idx3 = np.tile([0, -1, 1], (p, 1))
    w3 = np.column_stack([w2[:, 0], np.full(p, 7.0), w2[:, 1]])  # big weight on the padding slot
    padded = deform(coords, make_rig(SkinWeights(idx3, w3), rest, dqs=dqs), [pose])
    np.testing.assert_allclose(padded, plain, atol=ATOL)
    only_pad = deform(coords, make_rig(SkinWeights(np.full((p, 1), -1), np.ones((p, 1))), rest, dqs=dqs), [pose])
    np.testing.assert_allclose(only_pad, coords, atol=ATOL)


@pytest.mark.parametrize("dqs", [False, True])
def test_vertex_mask(rng, dqs):
    p = 9
    coords = rng.normal(size=(p, 3))
    rest = random_rigid(rng)[None]
    pose = random_rigid(rng, 2.0)[None]
    mw, aw = random_affine(rng), random_affine(rng)
    sw = SkinWeights(np.zeros((p, 1), int), np.full((p, 1), 0.7))
    mask = np.array([0, 0, 0, 0.5, 0.5, 0.5, 1, 1, 0.25])
    out = deform(coords, make_rig(sw, rest, mw, aw, dqs=dqs, mask=mask), [pose])
    full = apply(object_space_matrix(pose[0], rest[0], mw, aw), coords)
    expected = coords + mask[:, None] * (full - coords)
    np.testing.assert_allclose(out, expected, atol=1e-9)
    np.testing.assert_allclose(out[:3], coords[:3], rtol=0, atol=1e-12)


def test_lbs_vertex_mask_two_bones_half_displacement(rng):
    p = 15
    coords = rng.normal(size=(p, 3))
    rest = np.stack([random_rigid(rng) for _ in range(2)])
    pose = np.stack([random_rigid(rng) for _ in range(2)])
    sw = SkinWeights(np.tile([0, 1], (p, 1)), rng.uniform(0.1, 1, size=(p, 2)))
    mw, aw = random_affine(rng), random_affine(rng)
    full = deform(coords, make_rig(sw, rest, mw, aw), [pose])
    half = deform(coords, make_rig(sw, rest, mw, aw, mask=np.full(p, 0.5)), [pose])
    np.testing.assert_allclose(half - coords, 0.5 * (full - coords), atol=1e-9)


def test_modifier_stack_applies_in_order(rng):
    p = 12
    coords = rng.normal(size=(p, 3))
    mw = random_affine(rng)
    rest1, pose1, aw1 = random_rigid(rng)[None], random_rigid(rng)[None], random_affine(rng)
    rest2 = np.stack([random_rigid(rng) for _ in range(2)])
    pose2 = np.stack([random_rigid(rng) for _ in range(2)])
    aw2 = random_affine(rng)
    w2 = rng.uniform(0.1, 1, size=(p, 2))
    d1 = ArmatureDeform(SkinWeights(np.zeros((p, 1), int), np.ones((p, 1))), ["a"], rest1, aw1)
    d2 = ArmatureDeform(SkinWeights(np.tile([0, 1], (p, 1)), w2), ["x", "y"], rest2, aw2)
    out = deform(coords, SkinningRig(mw, [d1, d2]), [pose1, pose2])
    step1 = apply(object_space_matrix(pose1[0], rest1[0], mw, aw1), coords)
    mats2 = [object_space_matrix(pose2[i], rest2[i], mw, aw2) for i in range(2)]
    np.testing.assert_allclose(out, reference_lbs(step1, w2, mats2), atol=1e-9)


# --------------------------------------------------------------------- DQS
def _two_bone_same_axis(rng, a, b, weights, axis=(0.3, -0.5, 0.8), center=(1.0, 2.0, -0.5), p=30):
    coords = rng.normal(size=(p, 3)) * 2
    rest = np.stack([random_rigid(rng) for _ in range(2)])
    pose = np.stack([rotation_about_point(axis, ang, center) @ rest[i] for i, ang in enumerate((a, b))])
    sw = SkinWeights(np.tile([0, 1], (p, 1)), np.tile(weights, (p, 1)))
    return coords, rest, pose, sw


@pytest.mark.parametrize("a,b", [(0.3, 1.1), (np.radians(60), np.radians(100)), (-0.4, 0.9), (1.5, -1.5)])
def test_dqs_same_axis_half_weights_rotates_by_mean_angle(rng, a, b):
    axis, center = (0.3, -0.5, 0.8), (1.0, 2.0, -0.5)
    coords, rest, pose, sw = _two_bone_same_axis(rng, a, b, [0.5, 0.5], axis, center)
    out = deform(coords, make_rig(sw, rest, dqs=True), [pose])
    np.testing.assert_allclose(out, apply(rotation_about_point(axis, (a + b) / 2, center), coords), atol=1e-9)


def test_dqs_same_axis_unequal_weights_follows_quaternion_blend(rng):
    a, b, w1, w2 = 0.2, 1.6, 0.8, 0.2
    axis, center = (0.0, 0.0, 1.0), (0.5, -1.0, 0.0)
    coords, rest, pose, sw = _two_bone_same_axis(rng, a, b, [w1, w2], axis, center)
    out = deform(coords, make_rig(sw, rest, dqs=True), [pose])
    # normalised w1*q(a) + w2*q(b) for a common axis is a rotation by this angle:
    half = np.arctan2(w1 * np.sin(a / 2) + w2 * np.sin(b / 2), w1 * np.cos(a / 2) + w2 * np.cos(b / 2))
    np.testing.assert_allclose(out, apply(rotation_about_point(axis, 2 * half, center), coords), atol=1e-9)


def test_dqs_hemisphere_alignment_takes_short_path(rng):
    # +170 deg and -170 deg (= +190 deg): the short-path blend is a 180 deg turn, not identity
    a, b = np.radians(170), np.radians(-170)
    axis, center = (0.0, 1.0, 0.0), (0.0, 0.0, 0.0)
    coords, rest, pose, sw = _two_bone_same_axis(rng, a, b, [0.5, 0.5], axis, center)
    out = deform(coords, make_rig(sw, rest, dqs=True), [pose])
    np.testing.assert_allclose(out, apply(rotation_about_point(axis, np.pi, center), coords), atol=1e-9)


@pytest.mark.parametrize("theta", [np.radians(45), np.radians(90), np.radians(150)])
def test_dqs_twist_preserves_axis_distance_lbs_collapses(rng, theta):
    axis, center = np.array([0.0, 1.0, 0.0]), np.array([0.2, 0.0, -0.3])
    # ring of vertices around the twist axis
    ang = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    r0 = 0.7
    coords = np.column_stack([center[0] + r0 * np.cos(ang), np.linspace(-1, 1, 16), center[2] + r0 * np.sin(ang)])
    rest = np.stack([mat4(t=center), mat4(t=center + [0, 1, 0])])
    pose = np.stack([rotation_about_point(axis, s * theta, center) @ rest[i] for i, s in enumerate((1, -1))])
    sw = SkinWeights(np.tile([0, 1], (16, 1)), np.full((16, 2), 0.5))
    dqs = deform(coords, make_rig(sw, rest, dqs=True), [pose])
    lbs = deform(coords, make_rig(sw, rest, dqs=False), [pose])
    np.testing.assert_allclose(dist_to_axis(dqs, axis, center), r0, atol=1e-9)
    np.testing.assert_allclose(dist_to_axis(lbs, axis, center), r0 * abs(np.cos(theta)), atol=1e-9)
    assert dist_to_axis(lbs, axis, center).max() < 0.9 * r0  # LBS shrinks the twisted ring


# --------------------------------------------------------- quaternion helper
def _check_quats(R):
    q = matrix_to_quaternion(R)
    ref = Rotation.from_matrix(R).as_quat()                # x, y, z, w
    ref = np.concatenate([ref[..., 3:], ref[..., :3]], -1)  # -> w, x, y, z
    sign = np.sign(np.sum(q * ref, -1, keepdims=True))
    np.testing.assert_allclose(q, sign * ref, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-14)


def test_matrix_to_quaternion_matches_scipy_random():
    _check_quats(Rotation.random(200, random_state=7).as_matrix())


@pytest.mark.parametrize("axis", [(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (0.2, -0.7, 0.4)])
@pytest.mark.parametrize("angle", [0.0, 1e-7, np.pi / 2, np.pi - 1e-6, np.pi])
def test_matrix_to_quaternion_all_branches(axis, angle):
    _check_quats(rot_axis_angle(axis, angle)[None])


def test_matrix_to_quaternion_batch_shape():
    R = Rotation.random(12, random_state=3).as_matrix().reshape(3, 4, 3, 3)
    q = matrix_to_quaternion(R)
    assert q.shape == (3, 4, 4)
    _check_quats(R.reshape(12, 3, 3))


# -------------------------------------------------------------- diagnostics
def test_diagnose_weights_counts():
    idx = np.array([[0, 1], [0, -1], [0, 1], [-1, -1], [1, 1], [0, 1], [0, 0]])
    w = np.array([[0.5, 0.5],    # ok
                  [0.3, 0.7],    # 0.3 real, 0.7 on padding -> unnormalised
                  [0.0, 0.0],    # unweighted
                  [1.0, 1.0],    # only padding -> unweighted
                  [0.7, 0.7],    # same bone twice, sum 1.4 -> unnormalised
                  [0.4, 0.6005],  # within the 1e-3 tolerance
                  [5e-5, 4e-5]])  # below the 1e-4 cut-off -> unweighted
    res = diagnose_weights(SkinWeights(idx, w))
    assert res.diagnostics == {"unweighted": 3, "unnormalised": 2}
    assert res.status == 1
    assert {i.code for i in res.issues} == {"unweighted_vertices", "unnormalised_weights"}
    np.testing.assert_allclose(res.value, [1.0, 0.3, 0.0, 0.0, 1.4, 1.0005, 9e-5])


def test_diagnose_weights_clean():
    res = diagnose_weights(SkinWeights(np.array([[0, 1], [1, -1]]), np.array([[0.25, 0.75], [1.0, 3.0]])))
    assert res.status == 0 and res.issues == []
    assert res.diagnostics == {"unweighted": 0, "unnormalised": 0}


# ------------------------------------------------------------------- errors
def test_errors():
    with pytest.raises(ShapeSpaceError):
        SkinWeights(np.zeros((3, 2), int), np.zeros((3, 3)))
    with pytest.raises(ShapeSpaceError):
        SkinWeights(np.zeros(3, int), np.zeros(3))
    sw = SkinWeights(np.zeros((3, 1), int), np.ones((3, 1)))
    with pytest.raises(ShapeSpaceError):
        ArmatureDeform(sw, ["a", "b"], np.eye(4)[None], np.eye(4))
    rig = make_rig(sw, np.eye(4)[None])
    with pytest.raises(ShapeSpaceError) as exc:
        deform(np.zeros((3, 3)), rig, [])
    assert "poses" in str(exc.value)
    with pytest.raises(ShapeSpaceError) as exc:
        deform(np.zeros((4, 3)), rig, [np.eye(4)[None]])
    assert exc.value.code == "vertex_count"
    with pytest.raises(ShapeSpaceError):
        deform(np.zeros((3, 3)), rig, [np.eye(3)[None]])


def test_normalised_weights_blend_as_linear_blend_skinning(rng):
    """Σ_k w̃_pk (M_k v_p − v_p) with the normalised, masked weights is linear blend skinning's displacement; rows
    below the contribution floor, and masked rows, do not move."""
    p = 12
    idx = rng.integers(-1, 4, size=(p, 3))
    w = rng.uniform(0.0, 1.0, size=(p, 3))
    w[0] = 0.0                                               # a vertex no bone holds
    sw = SkinWeights(idx, w)
    mats = np.stack([random_affine(rng) for _ in range(4)])
    co = rng.normal(size=(p, 3))
    mask = rng.uniform(0.0, 1.0, size=p)
    wn, bone = normalised_weights(sw, mask)
    moved = np.einsum("pkij,pj->pki", mats[bone][..., :3, :3], co) + mats[bone][..., :3, 3]
    ours = co + np.einsum("pk,pki->pi", wn, moved - co[:, None, :])
    np.testing.assert_allclose(ours, linear_blend_skinning(co, sw, mats, mask), atol=ATOL)
    np.testing.assert_array_equal(wn[0], 0.0)
