"""The middle step of Transfer Shapes (core/authoring/job.py) on synthetic rigs, against known answers.

Known answers (computed here from the construction): onto a rigidly moved, uniformly scaled copy of the source the
transferred sculpt of every key is ``s R S`` (S the key's full sculpt: an in-between's correction plus ``t`` times
its primary, a combination's correction plus its inputs); a vertex-group mask maps onto the copy unchanged; keys
not written stay zero.
"""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from core.authoring import LandmarkPairs, landmarks_from_indices
from core.authoring.job import (
    PreviewPlan,
    SourceRig,
    TargetMesh,
    TransferExample,
    TransferPlan,
    compute_preview,
    compute_transfer,
    map_weights,
)
from core.progress import Cancelled
from core.result import ShapeSpaceError, Status, exit_code
from test_authoring import _head, _landmarks, _shapes

NAMES = ["a", "b", "c", "b@0.5", "a+c"]


def _rig(V, T, D):
    """A rig of the three shapes, an in-between of ``b`` at 0.5 and a combination of ``a`` and ``c`` (their
    corrections are small bumps of their own), and a mask on ``c`` (weights rising along x)."""
    corr_ib = 0.3 * D[1] + 0.01 * np.sin(3 * V)
    corr_combo = -0.5 * D[2] + 0.02 * np.cos(2 * V)
    deltas = np.concatenate([D, corr_ib[None], corr_combo[None]])
    x = V[:, 0]
    weights = (x - x.min()) / np.ptp(x)
    n = len(NAMES)
    return SourceRig(name="Source", neutral=V, triangles=T, names=list(NAMES), deltas=deltas,
                     slider_min=np.zeros(n), slider_max=np.ones(n), mute=np.zeros(n, dtype=bool),
                     groups={"c": "MaskC"}, group_weights={"MaskC": weights},
                     inbetweens={"b@0.5": {"primary": "b", "at": 0.5}},
                     combinations={"a+c": {"inputs": ["a", "c"]}})


def _target(V, T):
    return TargetMesh(name="Target", neutral=V, triangles=T, keys=[], parts=1)


def _plan(rig, tgt, pairs, write=None, unmatched_parts="keep"):
    write = list(rig.names if write is None else write)
    return TransferPlan(source=rig.name, target=tgt.name, rig=rig, tgt=tgt, pairs=pairs,
                        names={n: n for n in rig.names}, write=write, replace=[],
                        skipped=[n for n in rig.names if n not in write], groups_clash=[], existing="refuse",
                        unmatched_parts=unmatched_parts, signature=(), started=0.0)


@pytest.fixture(scope="module")
def moved():
    """The head rig and its copy rotated, scaled by 2.5 and moved, with the landmark pairs of both."""
    V, T = _head()
    lm = _landmarks(V)
    R = Rotation.from_euler("xyz", [30, -50, 110], degrees=True).as_matrix()
    s, t = 2.5, np.array([3.0, -1.0, 7.0])
    TV = s * V @ R.T + t
    return _rig(V, T, _shapes(V)), _target(TV, T), landmarks_from_indices(V, TV, lm, lm), s, R


@pytest.mark.parametrize("unmatched_parts", ["keep", "move"])
def test_transfer_onto_a_moved_scaled_copy_gives_the_moved_scaled_sculpts(moved, unmatched_parts):
    rig, tgt, pairs, s, R = moved
    seen = []
    out = compute_transfer(_plan(rig, tgt, pairs, unmatched_parts=unmatched_parts), seen.append)
    D = rig.deltas
    sculpts = np.stack([D[0], D[1], D[2], D[3] + 0.5 * D[1], D[4] + D[0] + D[2]])
    expected = s * sculpts @ R.T
    assert np.abs(out.full - expected).max() < 1e-7 * np.abs(expected).max()
    np.testing.assert_allclose(out.masks["MaskC"], rig.group_weights["MaskC"], atol=1e-9)
    rep = out.report
    assert rep.status == Status.OK and rep.registration_status == Status.OK and not rep.issues
    assert rep.exit_code() == 0 and exit_code([rep]) == 0
    assert rep.landmarks == len(pairs) and rep.registration_residual_mm < 1e-6
    assert [k["name"] for k in rep.keys] == NAMES and not any(k["failed"] for k in rep.keys)
    data = rep.to_json()
    assert data["status"] == "ok" and data["registration_status"] == "ok" and data["issues"] == []
    assert seen[0] == 0.0 and seen[-1] == 1.0 and seen == sorted(seen)


def test_keys_not_written_stay_zero_and_are_reported_skipped(moved):
    rig, tgt, pairs, s, R = moved
    out = compute_transfer(_plan(rig, tgt, pairs, write=["a", "c"]))
    assert not out.full[[1, 3, 4]].any()
    expected = s * rig.deltas[[0, 2]] @ R.T
    assert np.abs(out.full[[0, 2]] - expected).max() < 1e-7 * np.abs(expected).max()
    assert out.report.skipped == ["b", "b@0.5", "a+c"]
    assert set(out.masks) == {"MaskC"}


def test_preview_registers_the_source_onto_the_copy(moved):
    rig, tgt, pairs, s, R = moved
    out = compute_preview(PreviewPlan(source="Source", target="Target", rig=rig, tgt=tgt, pairs=pairs, signature=()))
    assert out.result.status == Status.OK
    assert np.abs(out.result.value.registered - tgt.neutral).max() < 1e-9 * s


def test_a_failed_registration_is_refused_naming_both_meshes():
    """Landmarks pairing the head with points far off the target: nothing to match, refused by name."""
    V, T = _head()
    lm = _landmarks(V)
    far = V * [1.0, 1.0, 0.05] + [0, 0, 5.0]
    pairs = LandmarkPairs(V[lm], V[lm] * 3.0 + [0, 0, -20.0], lm, np.full(len(lm), -1))
    rig = _rig(V, T, _shapes(V))
    with pytest.raises(ShapeSpaceError, match="registration of 'Source' onto 'Target' failed: no part of the target"):
        compute_transfer(_plan(rig, _target(far, T), pairs))
    with pytest.raises(ShapeSpaceError, match="registration of 'Source' onto 'Target' failed"):
        compute_preview(PreviewPlan(source="Source", target="Target", rig=rig, tgt=_target(far, T), pairs=pairs,
                                    signature=()))


def test_cancelled_mid_way_raises_before_any_outcome(moved):
    rig, tgt, pairs, _, _ = moved
    calls = []

    def progress(fraction):
        calls.append(fraction)
        if fraction >= 0.7:
            raise Cancelled()

    with pytest.raises(Cancelled):
        compute_transfer(_plan(rig, tgt, pairs), progress)
    assert calls[-1] == 0.7


def test_map_weights_interpolates_barycentrically_and_zeroes_unmapped_vertices():
    class Corr:
        tri = np.array([0, 1, -1])
        bary = np.array([[0.2, 0.3, 0.5], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    tris = np.array([[0, 1, 2], [3, 2, 1]])
    weights = np.array([0.0, 1.0, 0.5, 2.0])
    out = map_weights(Corr(), tris, weights)
    np.testing.assert_allclose(out, [0.2 * 0.0 + 0.3 * 1.0 + 0.5 * 0.5, 1.0, 0.0])   # 2.0 clipped to 1


def test_a_part_held_still_stays_still_when_an_example_moves_it(moved):
    """A part set still (``TransferPlan.part_kinds``) is still in every written key, also where an example's
    residual would be spread onto it (the examples' refinement runs after the parts are moved)."""
    rig, tgt, pairs, s, R = moved
    box = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float) * 0.05 * s + tgt.neutral.mean(axis=0)
    tris = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]) + len(tgt.neutral)
    with_box = TargetMesh(name="Target", neutral=np.vstack([tgt.neutral, box]),
                          triangles=np.vstack([tgt.triangles, tris]), keys=[], parts=2)
    held = np.arange(len(tgt.neutral), len(with_box.neutral))
    plan = _plan(rig, with_box, pairs, write=["a", "b", "c"], unmatched_parts="move")
    plan.part_kinds = {int(held[0]): ("still", "set by the user")}
    plain = compute_transfer(plan).full[1]
    assert not plain[held].any()
    example = plain + 0.1 * s                                          # every row moved, the box included
    plan.examples = [TransferExample(key="ex", deltas=example, weights={"b": 1.0})]
    out = compute_transfer(plan)
    assert not out.full[:, held].any()                                 # held still in every key
    skin = np.setdiff1d(np.arange(len(with_box.neutral)), held)
    np.testing.assert_allclose(out.full[1, skin], example[skin], atol=1e-9 * s)   # the example met elsewhere
