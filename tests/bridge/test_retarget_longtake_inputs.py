"""Bad long-take inputs (#11): a take of 2 frames, every channel constant, every frame clipping, and 36,000
frames of NaN except one channel — through the core API, the bridge and the batch command.  Each gives a
one-line refusal or a correct result with a warning, never a traceback or a silent wrong answer."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from blender_support import bpy, import_file
from shapespace.bridge import actions, retarget, shapekeys
from shapespace.core.keyreduce import reduce_keys_bezier, reduce_keys_bezier_curves
from shapespace.core.result import ShapeSpaceError
from shapespace.core.retarget import copy_weights, split_mapping
from shapespace.core.retarget.capture import read_live_link_csv
from support import ASSETS, ROOT

CSV = os.path.join(ASSETS, "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")
BLEND = os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend")
RUN_CLI = os.path.join(ROOT, "tools", "run_cli.py")

with open(CSV, encoding="utf-8") as _fh:
    HEADER = _fh.readline().strip()
CHANNELS = HEADER.split(",")[2:]                      # after Timecode, BlendShapeCount (52 ARKit + 9 head/eye)


def _timecode(k: int) -> str:
    t = k / 60.0
    h, rem = divmod(t, 3600.0)
    m, rem = divmod(rem, 60.0)
    s = int(rem)
    return f"{int(h):02d}:{int(m):02d}:{s:02d}:{(rem - s) * 60:06.3f}"


def _write(path, rows: int, cell) -> str:
    """A Live Link Face CSV of ``rows`` rows at 60 fps; ``cell(row, channel name)`` gives each text cell."""
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(HEADER + "\n")
        for k in range(rows):
            fh.write(f"{_timecode(k)},61," + ",".join(cell(k, c) for c in CHANNELS) + "\n")
    return str(path)


def _cli(*args):
    proc = subprocess.run([sys.executable, RUN_CLI, BLEND, "--", "retarget", *args], capture_output=True, text=True,
                          timeout=900, env=dict(os.environ))
    return proc.returncode, proc.stdout, proc.stderr


def _errors(stderr):
    return [ln for ln in stderr.splitlines() if ln.startswith("shapespace: error:")]


def _curve_values(ob, action_name, frames):
    """Blender's own evaluation of every shape-key curve of the result at ``frames``: {name: (f,)}."""
    curves = actions.shape_key_curves(ob, bpy.data.actions[action_name])
    return {n: np.array([fc.evaluate(float(f)) for f in frames]) for n, fc in curves.items()}


@pytest.fixture
def takes(tmp_path):
    head = [c for c in CHANNELS if not c.startswith(("Head", "LeftEye", "RightEye"))]
    return {
        "two": _write(tmp_path / "two_frames.csv", 2, lambda k, c: "0.5"),
        "two_scene": _write(tmp_path / "two_scene_frames.csv", 3, lambda k, c: "0.5"),    # 2 frames at 30 fps
        "three": _write(tmp_path / "three_frames.csv", 5, lambda k, c: "0.5"),        # 3 frames at 30 fps
        "constant": _write(tmp_path / "constant.csv", 600, lambda k, c: "0.25"),
        "clip": _write(tmp_path / "clip.csv", 600, lambda k, c: "1.4" if c in head else "0"),
        "nan": _write(tmp_path / "nan_36000.csv", 36000, lambda k, c: f"{0.3 + 0.2 * np.sin(k / 50):.4f}"
                      if c == "JawOpen" else "nan"),
    }


def test_two_frames_refused_three_frames_retargeted(takes):
    with pytest.raises(ShapeSpaceError) as exc:
        read_live_link_csv(takes["two"])
    assert exc.value.code == "too_short" and "at least 3" in str(exc.value)
    import_file(BLEND)
    ob = bpy.data.objects["FBHead"]
    before = set(bpy.data.actions.keys())
    for method in ("copy", "perframe", "spacetime"):
        for take in (takes["two"], takes["two_scene"]):               # 2 rows; 3 rows = 2 frames at 30 fps
            with pytest.raises(ShapeSpaceError) as exc:
                retarget.retarget(ob, take, method, key_tolerance=0.01)
            assert str(exc.value).startswith(take) and "at least 3" in str(exc.value)
    assert set(bpy.data.actions.keys()) == before                       # nothing written
    for method in ("copy", "perframe", "spacetime"):                   # the minimum: exact, nothing clips
        rep = retarget.retarget(ob, takes["three"], method, key_tolerance=0.01)
        assert rep["frames"] == 3
        got = _curve_values(ob, rep["action"], [1, 2, 3])
        for name, values in got.items():
            assert np.allclose(values, 0.5, atol=2e-3), (method, name, values)
    # the key reduction itself on the shortest curves: every sample kept, values exact
    idx, kv, km = reduce_keys_bezier([1.0, 2.0], [0.2, 0.7], 0.01)
    assert idx.tolist() == [0, 1] and kv.tolist() == [0.2, 0.7]
    assert all(k[0].tolist() == [0, 1] for k in reduce_keys_bezier_curves([1.0, 2.0], np.eye(2), 0.01))


def test_every_channel_constant_gives_the_constant_with_two_keys_per_curve(takes):
    stream = read_live_link_csv(takes["constant"])
    assert np.all(stream.weights == 0.25)
    import_file(BLEND)
    ob = bpy.data.objects["FBHead"]
    for method in ("copy", "perframe", "spacetime"):
        rep = retarget.retarget(ob, takes["constant"], method, key_tolerance=0.01)
        frames = np.arange(1, rep["frames"] + 1)
        curves = actions.shape_key_curves(ob, bpy.data.actions[rep["action"]])
        assert all(len(fc.keyframe_points) == 2 for fc in curves.values())
        for name, values in _curve_values(ob, rep["action"], frames[::37]).items():
            np.testing.assert_allclose(values, 0.25, atol=2e-3, err_msg=f"{method} {name}")
        assert rep["clipping_frames"] == 0
        for value in (rep.position_error_rms, rep.velocity_error_rms):
            assert value is None or np.isfinite(value)
        if method == "spacetime":
            assert rep.converged


def test_every_frame_clipping_is_bounded_reported_and_agrees_across_fits(takes):
    stream = read_live_link_csv(takes["clip"])
    assert any(i.code == "weights_out_of_range" for i in stream.issues)
    import_file(BLEND)
    ob = bpy.data.objects["FBHead"]
    model = shapekeys.read_blendshape_model(ob)
    results = {}
    for method in ("copy", "perframe", "spacetime"):
        rep = retarget.retarget(ob, takes["clip"], method)
        frames = np.arange(1, rep["frames"] + 1)
        assert rep["clipping_frames"] == rep["frames"]                 # every frame clips, and the report says so
        assert any("leave the weight range" in i.message for i in rep.issues)
        got = _curve_values(ob, rep["action"], frames[::50])
        W = np.column_stack([got[n] for n in model.names])
        assert np.all(W >= model.slider_min - 1e-6) and np.all(W <= model.slider_max + 1e-6)
        results[method] = W
        if method == "spacetime":
            assert rep.converged
    assert np.all(np.abs(results["copy"] - np.where(results["copy"] > 0.5, 1.0, 0.0)) < 1e-6)
    # geometry: the fits are the bounded optimum of ‖(W − ideal) Bᵀ‖ per frame (the rig's near-ties aside, their
    # weights may differ), far better than clipping the weights
    names, _, src, _ = retarget.read_source(takes["clip"], bpy.context.scene)
    mapping, _ = retarget.resolve_mapping(ob, names, model.names)
    pairs, gain, offset = split_mapping(mapping, model.n_targets)
    ideal = copy_weights(src[:1], pairs, model.n_targets, gain, offset)[0]
    err = {m: np.linalg.norm((W - ideal) @ model.delta_matrix.T, axis=1) for m, W in results.items()}
    assert np.all(err["perframe"] <= err["copy"] * (1 + 1e-9))
    assert np.all(err["spacetime"] <= err["perframe"] * 1.01 + 1e-9)


def test_36000_frames_of_nan_but_one_channel_is_one_line_refusal(takes):
    with pytest.raises(ShapeSpaceError) as exc:
        read_live_link_csv(takes["nan"])
    message = str(exc.value)
    assert exc.value.code == "non_finite" and "\n" not in message
    assert message.startswith(takes["nan"]) and "51 of 52 channels" in message and "36000 rows" in message
    import_file(BLEND)
    ob = bpy.data.objects["FBHead"]
    before = set(bpy.data.actions.keys())
    with pytest.raises(ShapeSpaceError) as exc:
        retarget.retarget(ob, takes["nan"], "spacetime", key_tolerance=0.01)
    assert "51 of 52 channels" in str(exc.value)
    assert set(bpy.data.actions.keys()) == before


def test_batch_command_one_line_per_bad_take_and_results_for_the_rest(takes, tmp_path):
    report = tmp_path / "report.json"
    order = ("two", "constant", "nan", "clip")
    code, out, err = _cli(*sum((["--source", takes[k]] for k in order), []), "--key-tolerance", "0.01",
                          "--dry-run", "--report", str(report))
    assert code == 1                                                   # some sources failed
    assert "Traceback" not in err
    lines = _errors(err)
    assert len(lines) == 2, err
    assert lines[0].startswith(f"shapespace: error: {takes['two']}: ") and "at least 3" in lines[0]
    assert lines[1].startswith(f"shapespace: error: {takes['nan']}: ") and "51 of 52 channels" in lines[1]
    results = {os.path.basename(r["source"]): r for r in json.loads(report.read_text())["results"]}
    assert not results["two_frames.csv"]["ok"] and not results["nan_36000.csv"]["ok"]
    const, clip = results["constant.csv"], results["clip.csv"]
    assert const["ok"] and const["clipping_frames"] == 0 and const["converged"]
    assert const["keys_kept_frac"] == pytest.approx(2 / const["frames"])
    assert clip["ok"] and clip["clipping_frames"] == clip["frames"] and clip["converged"]
    assert any(f"warning: {takes['clip']}: " in ln and "leave the weight range" in ln for ln in err.splitlines())
