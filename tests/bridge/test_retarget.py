"""`shapespace retarget`: Live Link Face CSV and actions onto shape-key rigs, batch and bad input."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from support import ASSETS, ROOT, shared
from blender_support import bpy, import_file
from shapespace.bridge import actions, retarget, shapekeys
from shapespace.core.capture import read_live_link_csv, resample

CSV = os.path.join(ASSETS, "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")
BLEND = os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend")
RUN_CLI = os.path.join(ROOT, "tools", "run_cli.py")


def test_copy_matches_resampled_capture():
    import_file(BLEND)
    ob = bpy.data.objects["FBHead"]
    scene = bpy.context.scene
    rep = retarget.retarget(ob, CSV, "copy")
    stream = read_live_link_csv(CSV)
    frames, w = resample(stream.times, stream.weights, scene.render.fps, scene.frame_start)
    jaw = stream.names.index("JawOpen")
    curves = actions.shape_key_curves(ob, bpy.data.actions[rep["action"]])
    got = actions.sample_curve(curves["JawOpen"], frames)
    np.testing.assert_allclose(got, np.clip(w[:, jaw], 0, 1), atol=1e-6)
    assert rep["frames"] == frames.size and rep["mapped_channels"] == 51


def test_spacetime_keeps_the_motion_where_the_target_cannot_follow():
    """facecap capture → facecap with reduced slider ranges: space-time keeps velocities (Fig. 3.9)."""
    import_file(os.path.join(ASSETS, "facecap", "facecap_decoded.glb"))
    ob = bpy.data.objects["Mesh_2"]
    key = ob.data.shape_keys
    capture = actions.active_action(key)
    key.animation_data.action = None
    for name in ("jawOpen", "mouthSmile_L", "mouthSmile_R", "eyeBlink_L", "eyeBlink_R"):
        key.key_blocks[name].slider_max = 0.4
    reports = {m: retarget.retarget(ob, capture, m) for m in ("perframe", "spacetime")}
    assert reports["spacetime"]["clipping_frames"] > 0
    assert reports["spacetime"]["velocity_error_rms"] < reports["perframe"]["velocity_error_rms"]
    model = shapekeys.read_blendshape_model(ob)
    curves = actions.shape_key_curves(ob, bpy.data.actions[reports["spacetime"]["action"]])
    for name in model.names:
        kx, ky, _ = actions.read_curve(curves[name])
        assert ky.max() <= key.key_blocks[name].slider_max + 1e-6 and ky.min() >= key.key_blocks[name].slider_min - 1e-6


def _cli(*args):
    proc = subprocess.run([sys.executable, RUN_CLI, *args], capture_output=True, text=True, timeout=600,
                          env=dict(os.environ))
    return proc.returncode, proc.stdout, proc.stderr


def test_batch_command_with_a_missing_source(tmp_path):
    out, report = tmp_path / "out.blend", tmp_path / "report.json"
    code, _, err = _cli(BLEND, "--", "retarget", "--source", CSV, "--source", str(tmp_path / "gone.csv"),
                        "--method", "spacetime", "--key-tolerance", "0.01", "--out", str(out), "--report",
                        str(report))
    assert code == 1
    assert [ln for ln in err.splitlines() if ln.startswith("shapespace: error:")] == [
        f"shapespace: error: {tmp_path / 'gone.csv'}: file not found: {tmp_path / 'gone.csv'}"]
    rep = json.loads(report.read_text())
    ok = [r for r in rep["results"] if r["ok"]]
    assert len(ok) == 1 and 0 < ok[0]["keys_kept_frac"] < 0.2 and ok[0]["status"] == "converged"
    assert out.stat().st_size > 0


@pytest.mark.parametrize("case", ["no_timecode", "two_frames", "no_channels"])
def test_bad_csv_is_a_one_line_error(tmp_path, case):
    bad = tmp_path / f"{case}.csv"
    if case == "no_timecode":
        bad.write_text("Time,JawOpen\n1,0.5\n2,0.6\n3,0.7\n")
    elif case == "two_frames":
        bad.write_text("Timecode,JawOpen\n00:00:00:01.0,0.5\n00:00:00:02.0,0.6\n")
    else:
        bad.write_text("Timecode,Foo\n00:00:00:01.0,0.5\n00:00:00:02.0,0.6\n00:00:00:03.0,0.6\n")
    code, _, err = _cli(BLEND, "--", "retarget", "--source", str(bad), "--method", "copy")
    lines = [ln for ln in err.splitlines() if ln.startswith("shapespace: error:")]
    assert code == 1 and len(lines) == 1
    assert {"no_timecode": "no Timecode column", "two_frames": "at least 3 are needed",
            "no_channels": "no ARKit blendshape columns"}[case] in lines[0]


def test_unknown_method_and_ambiguous_target(tmp_path):
    code, _, err = _cli(BLEND, "--", "retarget", "--source", CSV, "--method", "magic")
    assert code == 2
    code, _, err = _cli(shared("robot_expressive", "RobotExpressive.glb"), "--", "retarget", "--source", CSV)
    assert code == 1 and "choose one with --object" in err


def test_retarget_operator_and_its_bad_input(registered):
    import_file(BLEND)
    ob = bpy.data.objects["FBHead"]
    bpy.context.view_layer.objects.active = ob
    assert bpy.ops.shapespace.retarget(filepath=CSV, method="copy") == {"FINISHED"}
    assert actions.active_action(ob.data.shape_keys) is not None
    with pytest.raises(RuntimeError, match="choose a CSV file or an action"):
        bpy.ops.shapespace.retarget()
    with pytest.raises(RuntimeError, match="no CSV file or action named"):
        bpy.ops.shapespace.retarget(action="nothing")
