"""Named landmarks (issue #22 §3): the name set, contours, the landmark file, and a proposal that survives a
degenerate hypothesis.  Expected values come from the construction (a grid whose shortest paths are known)."""
import json

import numpy as np
import pytest

from core.authoring import LandmarkPairs, named, proposal
from core.authoring.features import boundary_loops
from core.errors import ErrorCode
from core.result import ShapeSpaceError, Status
from test_authoring import _five_shapes, _head


def _grid(nx=7, ny=5):
    """A flat nx × ny vertex grid in z = 0 (unit spacing), two triangles per cell along the ↘ diagonal."""
    x, y = np.meshgrid(np.arange(nx, dtype=float), np.arange(ny, dtype=float))
    V = np.stack([x.ravel(), y.ravel(), np.zeros(nx * ny)], axis=1)
    tris = []
    for j in range(ny - 1):
        for i in range(nx - 1):
            a, b, c, d = j * nx + i, j * nx + i + 1, (j + 1) * nx + i, (j + 1) * nx + i + 1
            tris += [[a, b, d], [a, d, c]]
    return V, np.array(tris)


def test_name_set_mirror_partners_and_contours():
    assert len(named.NAMES) == len(set(named.NAMES)) == 26
    for n in named.NAMES:
        m = named.mirror_name(n)
        assert named.mirror_name(m) == n
        assert (m == n) == (n in named.CENTRE)
        if n.endswith("_L"):
            assert m == n[:-2] + "_R"
    for first, middle, last in named.CONTOURS.values():
        assert {first, middle, last} <= set(named.NAMES)
    assert named.CONTOURS["lid_upper_L"] == ("eye_inner_L", "lid_upper_L", "eye_outer_L")
    with pytest.raises(ShapeSpaceError, match="'eye_L' is not a landmark name"):
        named.mirror_name("eye_L")


def test_contour_is_the_shortest_edge_path_through_the_middle_landmark():
    V, T = _grid()
    nx = 7
    # upper lid: corners on row 1 (vertices 7 and 13), middle on row 3 (vertex 3 * 7 + 3 = 24)
    marks = {"eye_inner_L": 1 * nx + 0, "lid_upper_L": 3 * nx + 3, "eye_outer_L": 1 * nx + 6,
             "lip_upper_inner": 2 * nx + 3, "mouth_corner_L": 2 * nx + 6, "mouth_corner_R": 2 * nx + 0}
    paths = named.contour_paths(V, T, marks)
    assert set(paths) == {"lid_upper_L", "lip_upper_inner"}
    lip = paths["lip_upper_inner"]                     # a straight row: every vertex of row 2, right to left
    np.testing.assert_array_equal(lip, [2 * nx + i for i in range(0, 7)])
    lid = paths["lid_upper_L"]
    assert lid[0] == 7 and lid[-1] == 13 and 24 in lid
    steps = np.linalg.norm(np.diff(V[lid], axis=0), axis=1)
    # from (0,1) to (3,3): 2 diagonal steps + 1 straight; back down to (6,1) against the diagonal: 2 + 3
    assert steps.sum() == pytest.approx(2 * np.sqrt(2) + 1 + 5)
    assert np.all(steps > 0.99)                         # consecutive mesh vertices
    with pytest.raises(ShapeSpaceError, match="no contour named 'lids'"):
        named.contour_paths(V, T, marks, names=("lids",))


def _file(source, target, version=1):
    return json.dumps({"version": version, "source": source, "target": target})


FIVE = {"eye_inner_L": 1, "eye_inner_R": 2, "nose_tip": 3, "mouth_corner_L": 4, "mouth_corner_R": 5, "chin": 6}


def test_landmark_file_parses_the_names_on_both_sides():
    tgt = {k: v + 10 for k, v in FIVE.items()}
    src, dst, ignored = named.parse_landmark_file(_file({**FIVE, "jaw_angle_L": 9}, tgt), "f.json", 20, 20)
    assert list(src) == [n for n in named.NAMES if n in FIVE]
    assert [dst[n] - src[n] for n in src] == [10] * 6
    assert ignored == ["jaw_angle_L"]


@pytest.mark.parametrize("source, target, version, n, message, code", [
    ({**FIVE, "eye_corner": 1}, FIVE, 1, None, "f.json.source.eye_corner: not a landmark name", "missing_key"),
    (FIVE, {**FIVE, "chin": -1}, 1, None, "f.json.target.chin: vertex -1 does not exist", "range"),
    (FIVE, {**FIVE, "chin": 99}, 1, 20, "f.json.target.chin: vertex 99 does not exist (the mesh has 20", "range"),
    (FIVE, {**FIVE, "chin": 2.5}, 1, None, "f.json.target.chin: the vertex index must be a whole number", "type"),
    (FIVE, {**FIVE, "chin": True}, 1, None, "f.json.target.chin: the vertex index must be a whole number", "type"),
    ({**FIVE, "chin": 1}, FIVE, 1, None, "f.json.source.chin: vertex 1 is already 'eye_inner_L'", "degenerate"),
    (FIVE, FIVE, 2, None, "f.json.version: 2 is not a supported landmark file version", "unsupported_file"),
    (FIVE, [1, 2], 1, None, "f.json.target: must be an object", "type"),
    ({"chin": 1, "nose_tip": 2}, FIVE, 1, None, "f.json: 2 landmark names are on both", "too_few_landmarks"),
])
def test_landmark_file_errors_name_the_entry(source, target, version, n, message, code):
    with pytest.raises(ShapeSpaceError) as err:
        named.parse_landmark_file(_file(source, target, version), "f.json", n, n)
    assert message in str(err.value) and err.value.code == code and "\n" not in str(err.value)


def test_landmark_file_not_json_or_without_target():
    with pytest.raises(ShapeSpaceError, match=r"^f.json: not valid JSON") as err:
        named.parse_landmark_file("{version: 1", "f.json")
    assert err.value.code == ErrorCode.CORRUPT_FILE
    with pytest.raises(ShapeSpaceError, match='f.json: no "target" object'):
        named.parse_landmark_file(json.dumps({"version": 1, "source": FIVE}), "f.json")


def test_head_file_round_trip_and_vertex_count(tmp_path):
    text = named.head_file_text(FIVE, 20, {"chin": "by hand"})
    path = tmp_path / "head.json"
    path.write_text(text)
    assert named.load_head_file(str(path), 20) == named.check_named(FIVE, "x")
    with pytest.raises(ShapeSpaceError, match="placed on a mesh of 20 vertices, this one has 21") as err:
        named.load_head_file(str(path), 21)
    assert err.value.code == ErrorCode.VERTEX_COUNT_MISMATCH


def test_boundary_loops_of_a_grid_with_a_hole():
    V, T = _grid()
    centre = 2 * 7 + 3
    loops = boundary_loops(len(V), T[~np.any(T == centre, axis=1)])    # the six triangles round the centre go
    sizes = sorted(len(loop) for loop in loops)
    assert sizes == [6, 20]                                               # the hole's rim, the outer border


def test_landmark_pairs_confidence_flags_and_json():
    P = np.arange(18, dtype=float).reshape(6, 3)
    lp = LandmarkPairs(P, P + 1, np.arange(6), np.arange(6), tuple("abcdef"), np.linspace(0, 1, 6),
                       np.array([1, 0, 0, 1, 0, 0], bool))
    kept = lp.unflagged()
    assert kept.names == ("b", "c", "e", "f") and not kept.flagged.any()
    np.testing.assert_array_equal(kept.source_index, [1, 2, 4, 5])
    back = LandmarkPairs.from_json(lp.to_json())
    np.testing.assert_array_equal(back.flagged, lp.flagged)
    np.testing.assert_allclose(back.confidence, lp.confidence)
    plain = LandmarkPairs(P, P)                               # placed by hand: sure of every pair
    assert plain.confidence.tolist() == [1.0] * 6 and not plain.flagged.any()
    assert LandmarkPairs.from_json({k: v for k, v in plain.to_json().items() if k not in ("confidence", "flagged")}
                                   ).confidence.tolist() == [1.0] * 6


def _collinear_on(calls):
    """A similarity that refuses (as on collinear points) on the given call numbers, else the real one."""
    real = proposal.similarity
    count = {"n": 0}

    def similarity(X, Y, *args):
        count["n"] += 1
        if count["n"] in calls:
            raise ShapeSpaceError("a similarity needs at least 3 points not on one line", ErrorCode.COLLINEAR)
        return real(X, Y, *args)
    return similarity


def test_proposal_survives_a_degenerate_hypothesis(monkeypatch):
    """ICT FaceKit as the source: one of the 24 starting alignments collapsed onto a line of target points and
    the whole proposal failed.  Now that start is skipped (counted) and the others decide."""
    V, T = _head()
    D = _five_shapes(V)
    TV = 0.5 * V + [1.0, 0.0, 0.0]
    monkeypatch.setattr(proposal, "similarity", _collinear_on({1}))
    res = proposal.propose_landmark_pairs(V, T, D, [f"s{i}" for i in range(6)], TV, T)
    assert res.status == Status.OK, res.message
    assert res.diagnostics["degenerate_hypotheses"] == 1
    np.testing.assert_array_equal(res.value.source_index, res.value.target_index)


def test_proposal_with_every_hypothesis_degenerate_fails_with_a_message(monkeypatch):
    V, T = _head()
    D = _five_shapes(V)
    monkeypatch.setattr(proposal, "similarity", _collinear_on(set(range(1, 10_000))))
    res = proposal.propose_landmark_pairs(V, T, D, [f"s{i}" for i in range(6)], V, T)
    assert res.status == Status.FAILED and res.value is None
    assert res.diagnostics["degenerate_hypotheses"] == 24 and "place landmarks by hand" in res.message
