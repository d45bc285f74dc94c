"""Final-shape examples and masked sculpts (issue #16): splitting, sparse storage, fingerprints, affine inversion."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from core.posespace.finalshape import (
    compare_fingerprints,
    decode_array,
    encode_array,
    lbs_affine_maps,
    split_by_masks,
    touched_vertices,
    uncovered_vertices,
)
from core.posespace.inversion import invert_affine, invert_deformation
from core.result import ShapeSpaceError, Status
from core.skinning import ArmatureDeform, SkinningRig, SkinWeights, deform


def _rig(rng, p=200, b=5, k=3, dqs=False, mask=False):
    rest = np.stack([np.eye(4)] * b)
    rest[:, :3, 3] = rng.normal(size=(b, 3))
    bi = rng.integers(-1, b, size=(p, k))
    w = rng.random((p, k))
    w[rng.random((p, k)) < 0.2] = 0.0
    pose = rest.copy()
    for i in range(b):
        m = np.eye(4)
        m[:3, :3] = Rotation.from_rotvec(rng.normal(size=3) * 0.4).as_matrix()
        m[:3, 3] = rng.normal(size=3) * 0.2
        pose[i] = m @ rest[i]
    world = np.eye(4)
    world[:3, :3] = Rotation.from_rotvec(rng.normal(size=3)).as_matrix() * 1.3
    world[:3, 3] = rng.normal(size=3)
    d = ArmatureDeform(weights=SkinWeights(bi, w), bone_names=[f"b{i}" for i in range(b)], rest=rest,
                       armature_world=np.eye(4), preserve_volume=dqs,
                       vertex_mask=rng.random(p) if mask else None)
    return SkinningRig(mesh_world=world, deformers=[d]), [pose]


@pytest.mark.parametrize("mask", [False, True])
def test_affine_maps_reproduce_linear_blend_skinning_and_invert_in_one_solve(mask):
    rng = np.random.default_rng(1)
    rig, poses = _rig(rng, mask=mask)
    co = rng.normal(size=(200, 3))
    maps = lbs_affine_maps(rig, poses)
    ours = np.einsum("pij,pj->pi", maps[:, :, :3], co) + maps[:, :, 3]
    np.testing.assert_allclose(ours, deform(co, rig, poses), atol=1e-12)
    sculpt = deform(co, rig, poses) + 0.05 * rng.normal(size=co.shape)
    res = invert_affine(maps, co, sculpt, lambda x: deform(x, rig, poses))
    assert res.status == Status.OK and res.iterations == 1
    np.testing.assert_allclose(deform(co + res.corrective, rig, poses), sculpt, atol=1e-10)
    ref = invert_deformation(lambda x: deform(x, rig, poses), co, sculpt)
    np.testing.assert_allclose(res.corrective, ref.corrective, atol=1e-8)


def test_affine_maps_only_for_one_linear_blend_deformer():
    rng = np.random.default_rng(2)
    rig, poses = _rig(rng, dqs=True)
    assert lbs_affine_maps(rig, poses) is None
    rig, poses = _rig(rng)
    bad = np.array(lbs_affine_maps(rig, poses))
    bad[:, :, 3] += 1.0                      # maps that do not describe the deformer: said so, not "ok"
    co = rng.normal(size=(200, 3))
    res = invert_affine(bad, co, deform(co, rig, poses), lambda x: deform(x, rig, poses))
    assert res.status == Status.NOT_CONVERGED
    collapsed = np.zeros((1, 3, 4))
    with pytest.raises(ShapeSpaceError, match="collapsed"):
        invert_affine(collapsed, np.zeros((1, 3)), np.ones((1, 3)))


def test_masks_split_a_corrective_into_parts_that_add_up_exactly():
    rng = np.random.default_rng(3)
    delta = rng.normal(size=(50, 3))
    masks = np.clip(rng.normal(size=(3, 50)), 0, None)
    masks[0, 5:] = np.maximum(masks[0, 5:], 0.05)
    masks[:, :5] = 0.0                       # five vertices no mask covers
    parts, rest = split_by_masks(delta, masks)
    np.testing.assert_allclose(parts.sum(axis=0) + rest, delta, rtol=0, atol=4e-16 * np.abs(delta).max())
    covered = masks.sum(axis=0) > 0
    assert np.all(rest[covered] == 0) and np.array_equal(rest[~covered], delta[~covered])
    share = masks[:, covered] / masks[:, covered].sum(axis=0)
    np.testing.assert_allclose(parts[:, covered], share[:, :, None] * delta[covered][None], atol=1e-15)
    assert np.all(parts[masks == 0] == 0)
    np.testing.assert_array_equal(uncovered_vertices(delta, masks, 1.0), np.arange(5))
    delta[2] = 0.0                           # an unmoved vertex is never "uncovered"
    np.testing.assert_array_equal(uncovered_vertices(delta, masks, 1.0), [0, 1, 3, 4])
    with pytest.raises(ShapeSpaceError, match="negative"):
        split_by_masks(delta, -masks)


def test_sparse_storage_round_trips_and_refuses_damage():
    rng = np.random.default_rng(4)
    pos = rng.normal(size=(7, 3))
    np.testing.assert_array_equal(decode_array(encode_array(pos, "<f4"), "<f4", 3, "x"), pos.astype(np.float32))
    idx = np.array([3, 9, 12])
    np.testing.assert_array_equal(decode_array(encode_array(idx, "<i4"), "<i4", 1, "x"), idx)
    with pytest.raises(ShapeSpaceError, match="not base64"):
        decode_array("%%%", "<f4", 3, "the final shape of example 'E'")
    with pytest.raises(ShapeSpaceError, match="whole number"):
        decode_array(encode_array(np.zeros(4), "<f4"), "<f4", 3, "x")
    d = np.zeros((4, 3))
    d[1, 2] = 1e-3
    d[3, 0] = 1e-9
    np.testing.assert_array_equal(touched_vertices(d, 1.0), [1])


def test_fingerprints_name_what_changed():
    stored = {"weights": "a", "modifiers": {"Armature": "m"}, "basis": "b",
              "bones": {"arm": list(np.eye(4).ravel()), "hand": list(np.eye(4).ravel())},
              "relative": list(np.eye(4).ravel())}
    same = dict(stored)
    assert compare_fingerprints(stored, same, ["arm", "hand"]) == []
    moved = dict(stored, bones={"arm": list((np.eye(4) * 1.1).ravel()), "hand": stored["bones"]["hand"]})
    assert compare_fingerprints(stored, moved, ["arm", "hand"]) == ["the rest pose of bone 'arm' changed"]
    gone = dict(stored, bones={"arm": stored["bones"]["arm"]}, weights="c")
    reasons = compare_fingerprints(stored, gone, ["arm"])
    assert reasons[0] == "bone 'hand' was deleted" and "skin weights of its sculpted vertices changed" in reasons
    mods = dict(stored, modifiers={"Armature": "x", "Smooth": "s"})
    assert compare_fingerprints(stored, mods, ["arm", "hand"]) == ["modifier 'Armature' changed",
                                                                   "modifier 'Smooth' was added"]
