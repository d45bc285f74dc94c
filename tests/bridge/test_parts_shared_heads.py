"""Facial parts on a shared head (issue #22 §1): ICT FaceKit's own ``jawOpen`` on its skin alone (every part
kept still) moves its lower teeth with the chin — against the rigid motion SciPy fits to the chin's vertices
(``Rotation.align_vectors``, Kabsch) and against the teeth ICT FaceKit's artist moved — and leaves the upper
teeth where they are."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import bench_transfer_v2
from blender_support import bpy, import_file
from shapespace.bridge import shapekeys
from shapespace.core.authoring import parts
from support import shared


def _ict():
    import_file(shared("ict_facekit", "ict_facekit_expressions.glb"))
    ob = bpy.data.objects["ICTFace"]
    me = ob.data
    me.calc_loop_triangles()
    tris = np.empty(len(me.loop_triangles) * 3, dtype=np.int32)
    me.loop_triangles.foreach_get("vertices", tris)
    model = shapekeys.read_blendshape_model(ob)
    return model.neutral, tris.reshape(-1, 3).astype(np.int64), model.deltas[list(model.names).index("jawOpen")]


def test_a_jaw_open_on_a_shared_head_moves_the_lower_teeth_with_the_chin():
    V, T, authored = _ict()
    lab, _ = parts.triangle_parts(len(V), T)
    skin_only = np.where((lab == 0)[:, None], authored, 0.0)
    plan = parts.propose_parts(V, T, lab, None, skin_only)
    out, _ = parts.move_parts(plan, V, T, skin_only[None].copy(), ["jawOpen"])
    lower = np.isin(lab, [p for p, k in plan.kinds.items() if k == "jaw"])
    upper = np.isin(lab, [p for p, k in plan.kinds.items() if k == "skull"])
    assert lower.sum() > 1000 and upper.sum() > 1000                   # ICT FaceKit: 16 lower, 16 upper teeth
    chin = parts.jaw_membership(V, lab, skin_only) > 0.9                 # the skin moving most with the jaw
    X, Y = V[chin], V[chin] + skin_only[chin]
    R, _ = Rotation.align_vectors(Y - Y.mean(axis=0), X - X.mean(axis=0))
    fitted = R.apply(V[lower] - X.mean(axis=0)) + Y.mean(axis=0) - V[lower]
    assert 10.0 < np.degrees(R.magnitude()) < 20.0                      # ICT FaceKit's jaw turns 15°
    assert np.linalg.norm(out[0, lower] - fitted) < 0.1 * np.linalg.norm(fitted)
    assert np.linalg.norm(out[0, lower] - authored[lower]) < 0.2 * np.linalg.norm(authored[lower])
    assert not out[0, upper].any()


def _whole(tag):
    """Neutral (n, 3), triangles (f, 3) and the authored ``jawOpen`` and ``tongueOut`` (n, 3) (zero where an
    object has no such key) of a whole head, world space, read as the transfer benchmark reads it."""
    head = bench_transfer_v2.read_head(tag)
    if head is None:                                                    # skipped without shared/, else named
        shared(bench_transfer_v2.HEADS[tag][0])
    V, T, D, names = head

    def key(name):
        return D[names.index(name)] if name in names else np.zeros_like(V)
    return V, T, key("jawOpen"), key("tongueOut")


@pytest.mark.parametrize("tag", sorted(bench_transfer_v2.HEADS))
def test_the_tongue_of_a_shared_head_is_the_part_its_artist_puts_out(tag):
    """On every shared head the parts proposed as the tongue (:data:`parts.TONGUE`, from the head's own
    ``jawOpen``) are exactly those its artist slides out in ``tongueOut`` (median motion over 5 % of the
    diagonal: Ready Player Me's two tongue shells; ICT FaceKit, Face Cap and FBHead put out none on a part
    that is a solid of the lower row), the teeth the artist moves in ``jawOpen`` go with the jaw, and those it
    leaves stay with the skull."""
    V, T, jaw_open, tongue_out = _whole(tag)
    lab, _ = parts.triangle_parts(len(V), T)
    plan = parts.propose_parts(V, T, lab, None, jaw_open)
    diag = parts.bbox_diagonal(V)
    rigid = [p for p, k in plan.kinds.items() if k in ("jaw", "skull")]
    out = {p for p in rigid if np.median(np.linalg.norm(tongue_out[lab == p], axis=1)) > 0.05 * diag}
    tongue = {p for p, r in plan.reasons.items() if r == parts.TONGUE}
    assert tongue == out and all(plan.kinds[p] == "jaw" for p in tongue)
    assert len(tongue) == {"rpm": 2}.get(tag, 0)
    moved = {p for p in rigid if np.median(np.linalg.norm(jaw_open[lab == p], axis=1)) > 0.01 * diag}
    assert all(plan.kinds[p] == "jaw" for p in moved)
    if tag in ("ict", "rpm"):                                 # every part keyed: the still ones are the skull's
        assert {p for p in rigid if plan.kinds[p] == "jaw"} == moved
