"""Issue #25 test rigs: the Rigify face is the rig a Blender user would make on the shared head — the human
meta-rig's face seated on the head's named landmarks (``tools/landmarks/facecap.json``), generated, bound with
automatic weights — checked on what Blender built: the generated rig's bones, the head's own evaluated surface,
the vertex groups bone heat wrote and the depsgraph's deformation when a control moves."""
import os

import numpy as np
import pytest

import rigs
from blender_support import bpy
from shapespace.bridge import rig as brig
from shapespace.core.authoring.named import load_head_file
from support import shared

#: mm at a 30 cm head (the bench's scale: a distance over the head's diagonal × 300).
HEAD_MM = 300.0
#: How close each seated bone end must be to its landmark (mm at a 30 cm head).
SEAT_MM = 2.0


def _mm(d, diag):
    return np.asarray(d) / diag * HEAD_MM


def _head_rest():
    path = shared(*rigs.FACECAP.split("/"))
    ob = rigs.load_head(path)
    return path, rigs.Rig(ob, None, None, "").world_points()


def _marks(n_verts):
    return load_head_file(os.path.join(rigs.LANDMARKS, "facecap.json"), n_verts)


def _top_group(ob, v):
    names = [g.name for g in ob.vertex_groups]
    return max(((g.weight, names[g.group]) for g in ob.data.vertices[v].groups), default=(0.0, ""))[1]


@pytest.fixture
def rigify():
    path, rest = _head_rest()
    rig = rigs.rigify_rig(path)
    return rig, rest


# bpy 4.2 crashes at interpreter exit once Rigify has been enabled (see test_rig.py): same exit guard.
@pytest.mark.gltf_export
@pytest.mark.rigify
def test_rigify_face_bones_sit_on_the_heads_landmarks_and_the_head_stays_put(rigify):
    rig, rest = rigify
    bpy.context.view_layer.update()
    diag = rigs.diagonal(rest)
    now = rig.world_points()
    # binding keeps the head where it was (no jump when it is parented to the generated rig) and the generated
    # rig at rest is the bind pose (the eyes look straight ahead: no lid moves)
    assert _mm(np.linalg.norm(now - rest, axis=1).max(), diag) < 0.5
    seats = rigs.rigify_seats(_marks(len(rest)), rest)
    M = np.array(rig.armature.matrix_world)
    for (bone, end), where in seats.items():
        b = rig.armature.data.bones[f"ORG-{bone}"]
        p = M[:3, :3] @ np.array(getattr(b, f"{end}_local")) + M[:3, 3]
        assert _mm(np.linalg.norm(p - where), diag) < SEAT_MM, (bone, end)
    # the jaw hinges behind the chin, above the jaw angles (under the ears), not at the chin
    marks = _marks(len(rest))
    jaw = rig.armature.data.bones["ORG-jaw"]
    hinge = M[:3, :3] @ np.array(jaw.head_local) + M[:3, 3]
    angles = rest[[marks["jaw_angle_L"], marks["jaw_angle_R"]]].mean(0)
    up = rest[marks["lip_upper_outer"]] - rest[marks["chin"]]
    up /= np.linalg.norm(up)
    assert (hinge - angles) @ up > 0.1 * diag


@pytest.mark.gltf_export
@pytest.mark.rigify
def test_rigify_automatic_weights_bind_lips_lids_and_jaw_to_their_bones(rigify):
    rig, rest = rigify
    ob = rig.mesh
    marks = _marks(len(rest))
    expect = {"lip_upper_outer": "DEF-lip.T.", "lip_upper_inner": "DEF-lip.T.", "lip_lower_outer": "DEF-lip.B.",
              "lip_lower_inner": "DEF-lip.B.", "mouth_corner_L": "DEF-lip.", "mouth_corner_R": "DEF-lip.",
              "lid_upper_L": "DEF-lid.T.L", "lid_upper_R": "DEF-lid.T.R", "lid_lower_L": "DEF-lid.B.L",
              "lid_lower_R": "DEF-lid.B.R", "jaw_angle_L": "DEF-jaw.L", "jaw_angle_R": "DEF-jaw.R",
              "brow_mid_L": "DEF-brow.T.L", "brow_mid_R": "DEF-brow.T.R", "nostril_L": "DEF-nose.L",
              "nostril_R": "DEF-nose.R"}
    for name, prefix in expect.items():
        assert _top_group(ob, marks[name]).startswith(prefix), (name, _top_group(ob, marks[name]))
    assert _top_group(ob, marks["chin"]) in ("DEF-chin", "DEF-chin.001", "DEF-jaw")


@pytest.mark.gltf_export
@pytest.mark.rigify
def test_rigify_controls_move_their_own_region_as_blender_evaluates_it(rigify):
    """The jaw opens the lower face (chin and lower lip, not the upper lip, nose or brows); an upper-lid control
    moves that lid, not the lower lid or the other eye."""
    rig, rest = rigify
    marks = _marks(len(rest))
    diag = rigs.diagonal(rest)
    c0 = brig.read_controls(rig.controls)
    labels = [ch.name for ch in rig.controls.channels]

    def moved(label, value):
        c = c0.copy()
        c[labels.index(label)] = value
        brig.apply_controls(rig.controls, c)
        d = _mm(np.linalg.norm(rig.world_points() - rest, axis=1), diag)
        brig.apply_controls(rig.controls, c0)
        return {n: d[v] for n, v in marks.items()}

    jaw = moved("jaw_master rotation X", 0.2)
    assert jaw["chin"] > 5.0 and jaw["lip_lower_outer"] > 0.4 * jaw["chin"], jaw
    for still in ("lip_upper_outer", "nose_tip", "brow_mid_L", "lid_upper_L"):
        assert jaw[still] < 0.1 * jaw["chin"], (still, jaw)
    lid = moved("lid.T.L.002 location Z", -0.05)
    assert lid["lid_upper_L"] > 1.0, lid
    for still in ("lid_lower_L", "lid_upper_R", "brow_mid_L", "chin"):
        assert lid[still] < 0.25 * lid["lid_upper_L"], (still, lid)


def test_hybrid_jaw_hinges_in_front_of_the_ears_and_opens_the_mouth():
    """The hybrid's jaw bone (``rigs.jaw_hinge``) sits where a rigger puts it: at the ears' height, just in front
    of them (facecap's head is Z-up facing -Y: its ears are the vertices farthest out sideways), on the midline;
    rotating it (Blender's evaluation) moves the chin and lower lip, barely the upper lip or the jaw angles."""
    path, rest = _head_rest()
    rig = rigs.hybrid_rig(path)
    diag = rigs.diagonal(rest)
    M = np.array(rig.armature.matrix_world)
    hinge = M[:3, :3] @ np.array(rig.armature.data.bones["jaw"].head_local) + M[:3, 3]
    ears = rest[np.abs(rest[:, 0]) > 0.9 * np.abs(rest[:, 0]).max()]
    assert ears[:, 2].min() < hinge[2] < ears[:, 2].max(), (hinge, ears[:, 2].min(), ears[:, 2].max())
    assert abs(hinge[1] - ears[:, 1].min()) < 0.05 * diag, (hinge, ears[:, 1].min())
    assert abs(hinge[0]) < 0.01 * diag
    marks = _marks(len(rest))
    c = brig.read_controls(rig.controls)
    c[0] = 0.3                                              # jaw rotation X
    brig.apply_controls(rig.controls, c)
    d = _mm(np.linalg.norm(rig.world_points() - rest, axis=1), diag)
    moved = {n: d[v] for n, v in marks.items()}
    assert moved["chin"] > 10.0 and moved["lip_lower_outer"] > 0.5 * moved["chin"], moved
    for still in ("lip_upper_outer", "jaw_angle_L", "jaw_angle_R", "nose_tip"):
        assert moved[still] < 0.35 * moved["chin"], (still, moved)
