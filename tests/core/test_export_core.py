"""core.export: weights an importer will not clamp, frame ranges, output checks, round-trip measures, farm merges."""
import json
import os
import stat

import numpy as np
import pytest

from core.export import (
    FORMATS,
    NEGATIVE_SUFFIX,
    check_format,
    check_output_path,
    chunk,
    export_range,
    format_of,
    match_vertices,
    merge_take_reports,
    recombine,
    roundtrip_error,
    sample_frames,
    split_weights,
    take_stem,
)
from core.export.farm import batch_status
from core.result import ShapeSpaceError, Status

# -- weights ---------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("lo,hi", [(-1.36, 1.72), (0.0, 1.72), (-1.36, 1.0), (-2.0, -0.5), (0.0, 1.0), (-3e-7, 1.0)])
def test_split_parts_stay_in_unit_range_and_recombine_exactly(lo, hi):
    rng = np.random.default_rng(0)
    w = np.concatenate([[lo, hi], rng.uniform(lo, hi, 500)])
    parts = split_weights(w)
    assert parts[0].suffix == ""                                   # the key keeps its name
    for p in parts:
        assert p.weights.min() >= 0.0 and p.weights.max() <= 1.0
    back = recombine(parts)
    scale = max(1.0, np.abs(w).max())
    assert np.abs(back - w).max() <= 4 * np.finfo(float).eps * scale + (3e-7 if lo > -1e-6 else 0.0)
    assert (len(parts) == 2) == (lo < -1e-6)
    if lo < -1e-6:
        assert parts[1].suffix == NEGATIVE_SUFFIX and parts[1].scale == pytest.approx(lo)


def test_in_range_weights_are_left_alone():
    w = np.linspace(0, 1, 11)
    (part,) = split_weights(w)
    assert part.scale == 1.0 and np.array_equal(part.weights, w)


def test_split_is_exact_between_samples_under_linear_interpolation():
    """max(w,0) and min(w,0) interpolate to w wherever the curve crosses 0 between two keys."""
    w = np.array([-1.2, 0.9, 1.7, -0.4])
    parts = split_weights(w)
    t = np.linspace(0, 3, 301)
    lerp = lambda y: np.interp(t, np.arange(4), y)
    assert np.abs(sum(p.scale * lerp(p.weights) for p in parts) - lerp(w)).max() < 1e-12


def test_split_refuses_nan():
    with pytest.raises(ShapeSpaceError) as err:
        split_weights([0.1, np.nan])
    assert err.value.code == "non_finite"


# -- frames ----------------------------------------------------------------------------------------------------

def test_export_range_is_the_actions_union_not_the_scene():
    assert export_range([(2.0, 335.0)], (1, 160)) == (2, 335)
    assert export_range([(1.14, 267.3), (5, 20)], (1, 250)) == (1, 268)
    assert export_range([], (1, 160)) == (1, 160)
    assert export_range([(2, 335)], (1, 160), override=(10, 20)) == (10, 20)


@pytest.mark.parametrize("override,code", [((20, 10), "range"), ((1.5, 3), "range"), ((1,), "usage"),
                                           ((0, 10 ** 6), "too_large")])
def test_bad_frame_ranges(override, code):
    with pytest.raises(ShapeSpaceError) as err:
        export_range([], (1, 10), override=override)
    assert err.value.code == code


def test_sample_frames_cover_both_ends():
    f = sample_frames(20, 183, 6)
    assert f[0] == 20 and f[-1] == 183 and len(f) == 6
    assert list(sample_frames(3, 4, 10)) == [3, 4]


# -- formats and output paths --------------------------------------------------------------------------------------

def test_formats_and_extensions(tmp_path):
    assert set(FORMATS) == {"gltf", "fbx", "abc"}
    assert format_of("x/a.GLB").name == "gltf" and format_of("a.abc").name == "abc"
    with pytest.raises(ShapeSpaceError) as err:
        check_format("usd")
    assert err.value.code == "format"
    with pytest.raises(ShapeSpaceError) as err:
        check_output_path(str(tmp_path / "a.fbx"), FORMATS["gltf"])
    assert err.value.code == "format"
    assert check_output_path(str(tmp_path / "a.gltf"), FORMATS["gltf"]) == str(tmp_path / "a.gltf")


def test_output_in_a_missing_or_read_only_folder_is_refused(tmp_path):
    with pytest.raises(ShapeSpaceError) as err:
        check_output_path(str(tmp_path / "gone" / "a.glb"), FORMATS["gltf"])
    assert err.value.code == "unwritable" and "does not exist" in str(err.value)
    ro = tmp_path / "ro"
    ro.mkdir()
    os.chmod(ro, stat.S_IRUSR | stat.S_IXUSR)
    try:
        with pytest.raises(ShapeSpaceError) as err:
            check_output_path(str(ro / "a.glb"), FORMATS["gltf"])
        assert err.value.code == "unwritable" and "read-only" in str(err.value)
    finally:
        os.chmod(ro, stat.S_IRWXU)
    locked = tmp_path / "locked.fbx"
    locked.write_bytes(b"old")
    os.chmod(locked, stat.S_IRUSR)
    with pytest.raises(ShapeSpaceError) as err:
        check_output_path(str(locked), FORMATS["fbx"])
    assert err.value.code == "unwritable"
    with pytest.raises(ShapeSpaceError) as err:
        check_output_path(str(tmp_path), FORMATS["fbx"])
    assert err.value.code == "format"                       # a folder has no .fbx extension
    folder = tmp_path / "dir.fbx"
    folder.mkdir()
    with pytest.raises(ShapeSpaceError) as err:
        check_output_path(str(folder), FORMATS["fbx"])
    assert err.value.code == "not_a_file"


def test_output_that_is_an_input_is_refused(tmp_path):
    src = tmp_path / "shot.abc"
    src.write_bytes(b"x")
    with pytest.raises(ShapeSpaceError) as err:
        check_output_path(str(src), FORMATS["abc"], inputs=(str(src),))
    assert err.value.code == "overwrite"


# -- round-trip measures ---------------------------------------------------------------------------------------------

def test_match_vertices_handles_split_and_reordered_vertices():
    rng = np.random.default_rng(1)
    src = rng.normal(size=(50, 3))
    order = np.concatenate([rng.permutation(50), [3, 7, 7]])          # reordered, some split (duplicated)
    mapping = match_vertices(src, src[order])
    assert np.array_equal(mapping, order)
    assert np.array_equal(match_vertices(src, src), np.arange(50))
    frames = np.stack([src, src * 1.1])
    err = roundtrip_error(frames, frames[:, order] + 1e-9, mapping)
    assert err.shape == (2,) and err.max() < 1e-8


# -- farm ------------------------------------------------------------------------------------------------------------

def _report(path, take, ok=True):
    res = {"source": take, "ok": ok, "action": f"FBHead_{take_stem(take)}"} if ok else \
        {"source": take, "ok": False, "error": f"file not found: {take}"}
    path.write_text(json.dumps({"target": "FBHead", "method": "spacetime", "results": [res]}))


def test_merge_reports_names_every_take(tmp_path):
    takes = ["/takes/a.csv", "/takes/b.csv", "/takes/gone.csv", "/takes/crashed.csv"]
    _report(tmp_path / "a.json", takes[0])
    _report(tmp_path / "b.json", takes[1])
    _report(tmp_path / "gone.json", takes[2], ok=False)
    (tmp_path / "a.blend").write_bytes(b"x")
    s = merge_take_reports(takes, str(tmp_path))
    assert s.takes == 4 and s.succeeded == takes[:2] and not s.ok
    assert [f["take"] for f in s.failed] == takes[2:]
    assert "file not found" in s.failed[0]["error"] and "did not finish" in s.failed[1]["error"]
    assert s.target == "FBHead" and s.method == "spacetime"
    assert s.results[0]["blend"] == str(tmp_path / "a.blend") and s.results[1]["blend"] is None
    assert json.loads(json.dumps(s.to_json()))["takes"] == 4


def test_chunks_and_duplicate_stems():
    assert chunk(["a.csv", "b.csv", "c.csv"], 2) == [["a.csv", "b.csv"], ["c.csv"]]
    with pytest.raises(ShapeSpaceError) as err:
        chunk(["x/a.csv", "y/a.csv"], 1)
    assert "a.json" in str(err.value)
    with pytest.raises(ShapeSpaceError):
        chunk(["a.csv"], 0)


# -- the status of a merged farm batch (the one exit rule: FAILED / NOT_CONVERGED exit 1) --------------------------

def test_batch_status_is_the_worst_take():
    ok = {"source": "a.csv", "ok": True, "converged": True, "status": "ok"}
    assert batch_status([], [ok]) == Status.OK
    assert batch_status([], [ok, {**ok, "status": "warning"}]) == Status.WARNING
    assert batch_status([], [ok, {**ok, "converged": False}]) == Status.NOT_CONVERGED
    assert batch_status([], [{**ok, "status": "not_converged"}, {**ok, "status": "warning"}]) == Status.NOT_CONVERGED
    assert batch_status([{"take": "b", "error": "no report"}], [{**ok, "converged": False}]) == Status.FAILED
