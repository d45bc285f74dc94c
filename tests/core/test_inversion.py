"""Rest-space inversion of posed sculpts (thesis 7.2.1) against per-vertex solves computed by hand."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from core.posespace.inversion import InversionResult, invert_deformation, vertex_jacobians
from core.result import ShapeSpaceError, Status
from core.skinning import ArmatureDeform, SkinningRig, SkinWeights, deform


# ------------------------------------------------------------------ helpers
def mat4(r=None, t=(0.0, 0.0, 0.0)):
    m = np.eye(4)
    m[:3, :3] = np.eye(3) if r is None else r
    m[:3, 3] = t
    return m


def rand_rot(rng):
    return Rotation.random(random_state=int(rng.integers(1 << 31))).as_matrix()


def random_rigid(rng, tscale=1.0):
    return mat4(rand_rot(rng), rng.normal(size=3) * tscale)


def random_world(rng):
    """Object world matrix: rotation, non-uniform positive scale, translation."""
    return mat4(rand_rot(rng) @ np.diag(rng.uniform(0.6, 1.8, size=3)), rng.normal(size=3) * 2.0)


def small_rigid(rng, max_angle=0.8):
    axis = rng.normal(size=3)
    r = Rotation.from_rotvec(axis / np.linalg.norm(axis) * rng.uniform(0.0, max_angle)).as_matrix()
    return mat4(r, rng.normal(size=3) * 0.5)


def random_affine_pose(rng, rest, common):
    """A general (non-rigid) posed bone matrix: a motion shared by the rig (``common``), a per-bone bend of
    up to ~45 degrees (so blended matrices stay well conditioned), and scale and shear in the bone frame."""
    S = np.eye(4)
    S[:3, :3] = np.diag(rng.uniform(0.7, 1.4, size=3)) + 0.15 * rng.normal(size=(3, 3))
    return common @ small_rigid(rng) @ rest @ S


def affine_poses(rng, rig):
    common = random_rigid(rng, 2.0)
    return np.stack([random_affine_pose(rng, r, common) for r in rig.deformers[0].rest])


def skin(rng, p, b, k=3, zero_rows=()):
    bi = np.stack([rng.permutation(b)[:k] for _ in range(p)])
    w = rng.uniform(0.05, 1.0, size=(p, k))
    bi[::7, -1] = -1                        # some padding
    for v in zero_rows:
        w[v] = 0.0
    return SkinWeights(bi, w)


def make_rig(rng, p=40, b=4, dqs=False, zero_rows=(3, 17)):
    weights = skin(rng, p, b, zero_rows=zero_rows)
    rest_b = np.stack([random_rigid(rng) for _ in range(b)])
    d = ArmatureDeform(weights, [f"bone{i}" for i in range(b)], rest_b, random_world(rng), preserve_volume=dqs)
    return SkinningRig(random_world(rng), [d])


def dense_weights(weights, b):
    out = np.zeros((weights.bone_index.shape[0], b))
    for v, (idx, ws) in enumerate(zip(weights.bone_index, weights.weight)):
        for i, w in zip(idx, ws):
            if i >= 0:
                out[v, i] += w
    return out


def reference_lbs_inverse(rig, pose, rest, sculpt):
    """Per vertex: blended matrix B = sum_i w_i M_i / sum_i w_i, then rest + delta = B^-1 sculpt."""
    d = rig.deformers[0]
    P = np.linalg.inv(d.armature_world) @ rig.mesh_world
    M = [np.linalg.inv(P) @ pose[i] @ np.linalg.inv(d.rest[i]) @ P for i in range(len(pose))]
    W = dense_weights(d.weights, len(pose))
    delta = np.empty_like(rest)
    for v in range(rest.shape[0]):
        tot = W[v].sum()
        if tot <= 1e-4:
            delta[v] = sculpt[v] - rest[v]
            continue
        B = sum(W[v, i] * M[i] for i in range(len(M))) / tot
        delta[v] = np.linalg.solve(B[:3, :3], sculpt[v] - B[:3, 3]) - rest[v]
    return delta


def qmul(a, b):
    """Hamilton product of (w, x, y, z) quaternions."""
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
                     w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def wxyz(R):
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return np.array([w, x, y, z])


def reference_rigid_dqs_inverse(rig, pose, rest, sculpt):
    """Dual-quaternion linear blending (rigid bones) per vertex, then the inverse of the blended rigid map."""
    d = rig.deformers[0]
    to_arm = np.linalg.inv(d.armature_world) @ rig.mesh_world
    dq = []
    for i in range(len(pose)):
        C = pose[i] @ np.linalg.inv(d.rest[i])
        r = wxyz(C[:3, :3])
        dq.append((r, 0.5 * qmul(np.r_[0.0, C[:3, 3]], r)))
    delta = np.empty_like(rest)
    for v in range(rest.shape[0]):
        rs, ds, tot = np.zeros(4), np.zeros(4), 0.0
        for i, w in zip(d.weights.bone_index[v], d.weights.weight[v]):
            if i < 0:
                continue
            s = -w if rs @ dq[i][0] < 0 else w       # hemisphere alignment against the running sum
            rs = rs + s * dq[i][0]
            ds = ds + s * dq[i][1]
            tot += w
        if tot <= 1e-4:
            delta[v] = sculpt[v] - rest[v]
            continue
        n2 = rs @ rs
        R = Rotation.from_quat(np.r_[rs[1:], rs[0]]).as_matrix()        # normalises
        t = 2.0 * qmul(ds, rs * np.array([1.0, -1, -1, -1]))[1:] / n2
        T = np.linalg.inv(to_arm) @ mat4(R, t) @ to_arm                 # object-space rigid map
        delta[v] = np.linalg.solve(T[:3, :3], sculpt[v] - T[:3, 3]) - rest[v]
    return delta


def size_of(rest):
    return float(np.linalg.norm(np.ptp(rest, axis=0)))


@pytest.fixture
def rng():
    return np.random.default_rng(31415)


# ------------------------------------------------------------------ linear blend skinning
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_lbs_inversion_exact_in_one_iteration(seed):
    rng = np.random.default_rng(seed)
    rig = make_rig(rng)
    pose = affine_poses(rng, rig)
    rest = rng.normal(size=(40, 3)) * 2.0
    size = size_of(rest)
    f = lambda x: deform(x, rig, [pose])
    sculpt = f(rest) + rng.normal(size=rest.shape) * 0.3 * size
    res = invert_deformation(f, rest, sculpt)
    assert isinstance(res, InversionResult)
    assert res.status == 0 and res.message == "converged"
    assert res.iterations == 1
    assert np.abs(f(rest + res.corrective) - sculpt).max() <= 1e-9 * size
    assert res.residual <= 1e-9 * size
    ref = reference_lbs_inverse(rig, pose, rest, sculpt)
    np.testing.assert_allclose(res.corrective, ref, rtol=0, atol=1e-9 * size)


def test_zero_weight_vertices_get_sculpt_minus_rest(rng):
    rig = make_rig(rng, zero_rows=(0, 5, 6, 30))
    pose = affine_poses(rng, rig)
    rest = rng.normal(size=(40, 3))
    f = lambda x: deform(x, rig, [pose])
    sculpt = f(rest) + rng.normal(size=rest.shape) * 0.2
    res = invert_deformation(f, rest, sculpt)
    for v in (0, 5, 6, 30):
        np.testing.assert_allclose(res.corrective[v], sculpt[v] - rest[v], rtol=0, atol=1e-12)


def test_already_matching_sculpt_needs_no_iteration(rng):
    rig = make_rig(rng)
    pose = affine_poses(rng, rig)
    rest = rng.normal(size=(40, 3))
    f = lambda x: deform(x, rig, [pose])
    res = invert_deformation(f, rest, f(rest))
    assert res.iterations == 0 and res.status == 0
    np.testing.assert_array_equal(res.corrective, 0.0)


# ------------------------------------------------------------------ dual-quaternion skinning
@pytest.mark.parametrize("seed", [3, 4, 5])
def test_dqs_rigid_inversion(seed):
    rng = np.random.default_rng(seed)
    rig = make_rig(rng, dqs=True)
    pose = np.stack([random_rigid(rng) for _ in range(4)])
    rest = rng.normal(size=(40, 3)) * 1.5
    size = size_of(rest)
    f = lambda x: deform(x, rig, [pose])
    sculpt = f(rest) + rng.normal(size=rest.shape) * 0.3 * size
    res = invert_deformation(f, rest, sculpt)
    assert res.status == 0 and 1 <= res.iterations <= 2
    assert np.abs(f(rest + res.corrective) - sculpt).max() <= 1e-9 * size
    ref = reference_rigid_dqs_inverse(rig, pose, rest, sculpt)
    np.testing.assert_allclose(res.corrective, ref, rtol=0, atol=1e-9 * size)


def test_dqs_with_per_bone_uniform_scale_converges(rng):
    rig = make_rig(rng, dqs=True)
    rest_b = rig.deformers[0].rest
    scales = [0.6, 1.0, 1.5, 2.2]
    pose = np.stack([random_rigid(rng) @ rest_b[i] @ np.diag([s, s, s, 1.0]) for i, s in enumerate(scales)])
    rest = rng.normal(size=(40, 3)) * 1.5
    size = size_of(rest)
    f = lambda x: deform(x, rig, [pose])
    sculpt = f(rest) + rng.normal(size=rest.shape) * 0.3 * size
    res = invert_deformation(f, rest, sculpt)
    assert res.status == 0 and res.iterations <= 4
    assert np.abs(f(rest + res.corrective) - sculpt).max() < 1e-9 * size
    for v in (3, 17):                                  # unweighted vertices are not moved by the skin
        np.testing.assert_allclose(res.corrective[v], sculpt[v] - rest[v], rtol=0, atol=1e-12 * size)


# ------------------------------------------------------------------ non-affine deformers
def twist_about_y(x, rate=0.8):
    """Rotate every point about the Y axis by an angle proportional to its height (a non-affine deformer)."""
    a = rate * x[:, 1]
    c, s = np.cos(a), np.sin(a)
    return np.stack([c * x[:, 0] + s * x[:, 2], x[:, 1], -s * x[:, 0] + c * x[:, 2]], axis=1)


def test_nonlinear_deformer_converges(rng):
    rest = rng.uniform(-1, 1, size=(30, 3))
    true_delta = rng.normal(size=rest.shape) * 0.1
    sculpt = twist_about_y(rest + true_delta)
    res = invert_deformation(twist_about_y, rest, sculpt)
    size = size_of(rest)
    assert res.status == 0 and 2 <= res.iterations <= 10
    assert np.abs(twist_about_y(rest + res.corrective) - sculpt).max() <= 1e-9 * size
    np.testing.assert_allclose(res.corrective, true_delta, rtol=0, atol=1e-8)


def test_custom_tolerance(rng):
    rest = rng.uniform(-1, 1, size=(10, 3))
    sculpt = twist_about_y(rest + 0.2)
    res = invert_deformation(twist_about_y, rest, sculpt, tol=1e-3)
    assert res.status == 0 and res.residual <= 1e-3
    assert np.abs(twist_about_y(rest + res.corrective) - sculpt).max() == pytest.approx(res.residual, rel=1e-12)


def test_unreachable_sculpt_is_reported_not_converged():
    rest = np.array([[0.0, 0.0, 0.0], [0.1, 0.2, 0.3], [1.0, 1.0, 1.0]])
    sculpt = np.sin(rest)
    sculpt[1] = [2.0, 2.0, 2.0]                     # outside the range of sin
    res = invert_deformation(np.sin, rest, sculpt, max_iter=8)
    assert res.status == Status.NOT_CONVERGED
    assert res.residual >= 1.0 - 1e-12            # |sin - 2| >= 1 everywhere
    assert np.abs(np.sin(rest + res.corrective) - sculpt).max() == pytest.approx(res.residual, rel=1e-12)


@pytest.mark.parametrize("saturating", [np.tanh, np.arctan, lambda x: x / (1.0 + np.abs(x))],
                         ids=["tanh", "arctan", "rational"])
def test_saturating_deformer_does_not_leak_linalg_error(saturating):
    rest = np.array([[0.0, 0.0, 0.0], [0.1, 0.2, 0.3], [1.0, 1.0, 1.0]])
    sculpt = saturating(rest)
    sculpt[1] = [2.0, 2.0, 2.0]                     # outside the deformer's range
    try:
        res = invert_deformation(saturating, rest, sculpt, max_iter=8)
    except ShapeSpaceError:
        return
    assert res.status == Status.NOT_CONVERGED


# ------------------------------------------------------------------ collapse and bad input
def test_rank_deficient_bone_scale_is_singular(rng):
    rig = make_rig(rng)
    d = rig.deformers[0]
    pose = np.stack([random_rigid(rng) @ r for r in d.rest])
    pose[1] = pose[1] @ np.diag([1.0, 0.0, 1.0, 1.0])      # bone 1 flattened along its Y axis
    d.weights.bone_index[:4] = [1, -1, -1]                  # vertices 0-3 follow only bone 1
    d.weights.weight[:4] = [1.0, 0.0, 0.0]
    rest = rng.normal(size=(40, 3))
    f = lambda x: deform(x, rig, [pose])
    with pytest.raises(ShapeSpaceError) as e:
        invert_deformation(f, rest, f(rest) + 0.1)
    assert e.value.code == "singular"


def collapse_rig(rest_b):
    """Vertices 0-2 follow only bone "a", which is scaled to zero; vertices 3-5 are shared with bone "b"."""
    bi = np.array([[0, -1]] * 3 + [[0, 1]] * 3)
    w = np.array([[1.0, 0.0]] * 3 + [[0.5, 0.5]] * 3)
    d = ArmatureDeform(SkinWeights(bi, w), ["a", "b"], rest_b, np.eye(4))
    pose = rest_b.copy()
    pose[0, :3, :3] = 0.0
    return SkinningRig(np.eye(4), [d]), pose


def collapse_to_point(x):
    out = x.copy()
    out[2] = [1.0, 2.0, 3.0]
    return out


@pytest.mark.parametrize("case", ["zero_scale_bone", "callable"])
def test_vertex_collapsed_to_a_point_is_singular(rng, case):
    if case == "zero_scale_bone":
        # identity rest matrices and world matrices: the collapsed vertices land exactly on the origin
        rig, pose = collapse_rig(np.stack([np.eye(4), mat4(t=(0.5, 0.0, 0.0))]))
        f = lambda x: deform(x, rig, [pose])
    else:
        f = collapse_to_point
    rest = rng.normal(size=(6, 3))
    with pytest.raises(ShapeSpaceError) as e:
        invert_deformation(f, rest, f(rest) + 0.1)
    assert e.value.code == "singular"


def test_zero_scale_bone_with_general_rest_matrices_is_singular():
    for seed in range(12):
        rng = np.random.default_rng(seed)
        rig, pose = collapse_rig(np.stack([random_rigid(rng) for _ in range(2)]))
        f = lambda x, rig=rig, pose=pose: deform(x, rig, [pose])  # noqa: E731
        rest = rng.normal(size=(6, 3))
        with pytest.raises(ShapeSpaceError) as e:
            invert_deformation(f, rest, f(rest) + 0.1)
        assert e.value.code == "singular"


@pytest.mark.parametrize("case, code", [
    ("count", "shape"), ("columns", "shape"), ("flat", "shape"), ("nan_rest", "non_finite"),
    ("inf_sculpt", "non_finite"),
])
def test_bad_input(rng, case, code):
    rest = rng.normal(size=(5, 3))
    sculpt = rest + 0.1
    if case == "count":
        sculpt = sculpt[:4]
    elif case == "columns":
        rest, sculpt = rest[:, :2], sculpt[:, :2]
    elif case == "flat":
        rest, sculpt = rest.ravel(), sculpt.ravel()
    elif case == "nan_rest":
        rest[1, 1] = np.nan
    elif case == "inf_sculpt":
        sculpt[0, 2] = np.inf
    with pytest.raises(ShapeSpaceError) as e:
        invert_deformation(lambda x: x, rest, sculpt)
    assert e.value.code == code


# ------------------------------------------------------------------ vertex_jacobians
def test_vertex_jacobians_of_affine_map(rng):
    p = 25
    A = rng.normal(size=(p, 3, 3))
    b = rng.normal(size=(p, 3))
    f = lambda x: np.einsum("pij,pj->pi", A, x) + b
    x = rng.normal(size=(p, 3))
    J = vertex_jacobians(f, x, 1e-2)
    assert J.shape == (p, 3, 3)
    np.testing.assert_allclose(J, A, rtol=0, atol=1e-12)
    # a single global matrix as well
    M = rng.normal(size=(3, 3))
    np.testing.assert_allclose(vertex_jacobians(lambda y: y @ M.T + 1.0, x, 0.5), np.broadcast_to(M, (p, 3, 3)),
                               rtol=0, atol=1e-13)


def test_vertex_jacobians_of_quadratic_map_are_exact(rng):
    # central differences are exact for quadratics: f(x) = (x0*x1, x2**2, x0 + 3 x1 x2)
    f = lambda x: np.stack([x[:, 0] * x[:, 1], x[:, 2] ** 2, x[:, 0] + 3 * x[:, 1] * x[:, 2]], axis=1)
    x = rng.normal(size=(10, 3))
    J = vertex_jacobians(f, x, 0.1)
    ref = np.zeros((10, 3, 3))
    ref[:, 0, 0], ref[:, 0, 1] = x[:, 1], x[:, 0]
    ref[:, 1, 2] = 2 * x[:, 2]
    ref[:, 2, 0], ref[:, 2, 1], ref[:, 2, 2] = 1.0, 3 * x[:, 2], 3 * x[:, 1]
    np.testing.assert_allclose(J, ref, rtol=0, atol=1e-13)


def test_vertex_jacobians_of_lbs_equal_blended_matrix(rng):
    rig = make_rig(rng)
    d = rig.deformers[0]
    pose = affine_poses(rng, rig)
    x = rng.normal(size=(40, 3))
    J = vertex_jacobians(lambda y: deform(y, rig, [pose]), x, 1e-3)
    P = np.linalg.inv(d.armature_world) @ rig.mesh_world
    M = np.stack([np.linalg.inv(P) @ pose[i] @ np.linalg.inv(d.rest[i]) @ P for i in range(4)])
    W = dense_weights(d.weights, 4)
    for v in range(40):
        tot = W[v].sum()
        ref = np.eye(3) if tot <= 1e-4 else np.einsum("i,ijk->jk", W[v], M[:, :3, :3]) / tot
        np.testing.assert_allclose(J[v], ref, rtol=0, atol=1e-10)
