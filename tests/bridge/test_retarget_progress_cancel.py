"""Retarget progress, Esc cancel, scene range and the clipped-frame report (#11 Build 6, #12 Builds 1 and 3).

The modal operator path (read on the main thread → compute in a worker → write on the main thread) is driven
here step by step through the bridge job functions the modal handler calls (no window in these tests); the
scripted operator call (EXEC_DEFAULT) is the synchronous path.
"""
import json
import os
import subprocess
import sys
import time

import numpy as np
import pytest

from blender_support import blend_fingerprint, bpy, esc_mid_way, import_file
from shapespace.bridge import actions, retarget, shapekeys
from shapespace.core.progress import Cancelled
from shapespace.core.result import ShapeSpaceError
from shapespace.core.retarget.capture import read_live_link_csv, resample
from support import ASSETS, ROOT

CSV = os.path.join(ASSETS, "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")
BLEND = os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend")
RUN_CLI = os.path.join(ROOT, "tools", "run_cli.py")
METHODS = ("copy", "perframe", "spacetime")


def _long_csv(path, repeats: int) -> str:
    """The shipped Live Link Face take played ``repeats`` times in a row (60 fps timecode, continuing)."""
    with open(CSV, encoding="utf-8") as fh:
        lines = fh.read().splitlines()
    out = [lines[0]]
    k = 0
    for _ in range(repeats):
        for row in lines[1:]:
            t = 3600.0 + k / 60.0
            h, rest = divmod(t, 3600.0)
            m, s = divmod(rest, 60.0)
            out.append(f"{int(h):02d}:{int(m):02d}:{int(s):02d}:{(s - int(s)) * 60.0:06.3f},{row.split(',', 1)[1]}")
            k += 1
    with open(path, "w", encoding="utf-8") as fh:
        fh.write("\n".join(out) + "\n")
    return str(path)


def _fbhead():
    import_file(BLEND)
    ob = bpy.data.objects["FBHead"]
    bpy.context.view_layer.objects.active = ob
    return ob


def _state(ob):
    """What the fingerprint leaves out and a retarget could change: scene range, the rig's action, the stored
    report, fake users, every action's curves."""
    scene = bpy.context.scene
    key = ob.data.shape_keys
    curves = {a.name: [(fc.data_path, tuple(np.array([k.co[:] for k in fc.keyframe_points]).ravel()))
                       for fc in actions.action_fcurves(a)] for a in bpy.data.actions}
    return (scene.frame_start, scene.frame_end, scene.frame_current, str(actions.active_action(key)),
            retarget.LAST_PROP in key, sorted((a.name, a.use_fake_user) for a in bpy.data.actions), curves,
            len(bpy.data.meshes), len(bpy.data.objects))


def _keys(action):
    """Every curve of an action: {data path: keyframe points (k, 2) and handles}."""
    out = {}
    for fc in actions.action_fcurves(action):
        pts = fc.keyframe_points
        co = np.empty(len(pts) * 2)
        pts.foreach_get("co", co)
        hl, hr = np.empty(len(pts) * 2), np.empty(len(pts) * 2)
        pts.foreach_get("handle_left", hl)
        pts.foreach_get("handle_right", hr)
        out[fc.data_path] = np.concatenate([co, hl, hr])
    return out


@pytest.mark.parametrize("method", METHODS)
def test_esc_mid_way_leaves_the_file_exactly_as_before(tmp_path, method):
    """Esc while the worker computes: the job stops at its next progress call, nothing is written (no action,
    no stored report, no scene range change), and the modal's finish step refuses to write anything."""
    ob = _fbhead()
    take = _long_csv(tmp_path / "long.csv", 10 if method == "copy" else 5)
    bpy.context.scene.frame_current = 7
    before, state = blend_fingerprint(), _state(ob)
    plan = retarget.read_retarget(ob, take, method, key_tolerance=0.01)          # invoke: main thread
    assert blend_fingerprint() == before and _state(ob) == state               # reading changed nothing
    job = retarget.start_retarget_job(plan)
    assert esc_mid_way(job, 0.2, 120)
    assert 0.2 <= max(job.reported) < 1.0
    with pytest.raises(Cancelled):
        retarget.finish_retarget_job(job, bpy.context.scene)
    assert blend_fingerprint() == before and _state(ob) == state
    assert not [a for a in bpy.data.actions if a.name.startswith("FBHead_")]


@pytest.mark.parametrize("method", METHODS)
def test_modal_path_writes_the_same_action_as_exec_default(registered, method):
    """The job driven to completion writes exactly what a scripted call (EXEC_DEFAULT) writes; the progress
    it reported rises monotonically to 1."""
    ob = _fbhead()
    job = retarget.start_retarget_job(retarget.read_retarget(ob, CSV, method, key_tolerance=0.01,
                                                             action_name="modal"))
    while not job.done:                                                          # the timer ticks
        time.sleep(0.01)
    rep = retarget.finish_retarget_job(job, bpy.context.scene)
    assert job.reported and all(b >= a for a, b in zip(job.reported, job.reported[1:]))
    assert job.reported[-1] == 1.0 and job.fraction == 1.0
    modal = bpy.data.actions[rep.action]
    assert bpy.ops.shapespace.retarget(filepath=CSV, method=method, key_tolerance=0.01) == {"FINISHED"}
    scripted = actions.active_action(ob.data.shape_keys)
    assert scripted != modal
    a, b = _keys(modal), _keys(scripted)
    assert a.keys() == b.keys() and len(a) == len(ob.data.shape_keys.key_blocks) - 1
    for path in a:
        np.testing.assert_array_equal(a[path], b[path])


@pytest.mark.parametrize("method", METHODS)
def test_progress_is_monotone_and_reaches_one(method):
    ob = _fbhead()
    seen = []
    retarget.retarget(ob, CSV, method, key_tolerance=0.01, progress=seen.append)
    assert len(seen) >= 10
    assert all(0.0 <= f <= 1.0 for f in seen)
    assert all(b >= a for a, b in zip(seen, seen[1:])) and seen[-1] == 1.0


def test_mesh_performance_progress_and_cancel(tmp_path):
    """A mesh performance: reading its frames reports progress too; cancelled while fitting, nothing changes
    and the scene is back on its frame."""
    import_file(os.path.join(ASSETS, "facecap", "facecap_decoded.glb"))
    src = bpy.data.objects["Mesh_2"]
    ob = _copy_rig(src)
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 120
    scene.frame_current = 5
    seen = []
    rep = retarget.retarget_dense(ob, src, "perframe", progress=seen.append)
    assert all(b >= a for a, b in zip(seen, seen[1:])) and seen[-1] == 1.0 and len(seen) > 120
    assert rep.frame_range == [1, 120] and not rep.scene_range_extended
    scene.frame_set(scene.frame_current)                # the result evaluated, as the UI shows it
    before, state = blend_fingerprint(), _state(ob)
    plan = retarget.read_retarget_dense(ob, src, "spacetime")
    assert scene.frame_current == 5 and blend_fingerprint() == before
    job = retarget.start_retarget_job(plan)
    esc_mid_way(job, 0.2, 120)
    with pytest.raises(Cancelled):
        retarget.finish_retarget_job(job)
    assert blend_fingerprint() == before and _state(ob) == state


def _copy_rig(src):
    """A separate rig with the same shapes as ``src`` (same topology)."""
    model = shapekeys.read_blendshape_model(src)
    me = bpy.data.meshes.new("TargetHead")
    me.from_pydata(model.neutral.tolist(), [], [list(p.vertices) for p in src.data.polygons])
    ob = bpy.data.objects.new("TargetHead", me)
    bpy.context.scene.collection.objects.link(ob)
    ob.shape_key_add(name="Basis")
    for k, name in enumerate(model.names):
        kb = ob.shape_key_add(name=name)
        kb.data.foreach_set("co", (model.neutral + model.deltas[k]).astype(np.float32).ravel())
    return ob


def test_rig_changed_while_computing_is_refused_and_nothing_written():
    ob = _fbhead()
    job = retarget.start_retarget_job(retarget.read_retarget(ob, CSV, "copy"))
    job.wait(120)
    ob.data.shape_keys.key_blocks["JawOpen"].slider_max = 0.5          # the artist edits the rig meanwhile
    before, state = blend_fingerprint(), _state(ob)
    with pytest.raises(ShapeSpaceError, match="changed while the retarget computed") as info:
        retarget.finish_retarget_job(job, bpy.context.scene)
    assert info.value.code == "rig_changed"
    assert blend_fingerprint() == before and _state(ob) == state


# ------------------------------------------------------------------ scene range (#12 Build 1)
def _capture_frames():
    stream = read_live_link_csv(CSV)
    scene = bpy.context.scene
    return resample(stream.times, stream.weights, scene.render.fps, scene.frame_start, scene.render.fps_base)


def test_operator_extends_the_scene_range_unless_told_not_to(registered, tmp_path):
    ob = _fbhead()
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 2, 160
    frames, _ = _capture_frames()
    assert frames[-1] > 160
    assert bpy.ops.shapespace.retarget(filepath=CSV, method="copy", extend_scene_range=False) == {"FINISHED"}
    assert (scene.frame_start, scene.frame_end) == (2, 160)
    assert retarget.last_report(ob).scene_range_extended is False
    assert bpy.ops.shapespace.retarget(filepath=CSV, method="copy", key_tolerance=0.01) == {"FINISHED"}
    action = actions.active_action(ob.data.shape_keys)
    first, last = actions.frame_range(action)
    assert (scene.frame_start, scene.frame_end) == (2, int(np.ceil(last)))
    assert first >= 2 and last == frames[-1]
    rep = retarget.last_report(ob)
    assert rep.frame_range == [int(frames[0]), int(frames[-1])] and rep.scene_range_extended
    path = str(tmp_path / "saved.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)
    scene = bpy.context.scene
    assert (scene.frame_start, scene.frame_end) == (2, int(frames[-1]))
    # the panel's setting (stored on the object) reaches the operator
    assert bpy.data.objects["FBHead"].shapespace_retarget.extend_scene_range is True


def test_discard_result_gives_the_scene_its_range_back(registered):
    ob = _fbhead()
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 2, 160
    assert bpy.ops.shapespace.retarget(filepath=CSV, method="copy") == {"FINISHED"}
    assert scene.frame_end > 160 and retarget.last_report(ob).scene_range_before == [2, 160]
    assert bpy.ops.shapespace.discard_retarget() == {"FINISHED"}
    assert (scene.frame_start, scene.frame_end) == (2, 160)
    # a range the artist changed after the retarget is theirs: discarding leaves it alone
    assert bpy.ops.shapespace.retarget(filepath=CSV, method="copy") == {"FINISHED"}
    scene.frame_end = 400
    assert bpy.ops.shapespace.discard_retarget() == {"FINISHED"}
    assert (scene.frame_start, scene.frame_end) == (2, 400)


def test_scene_range_only_ever_widens(registered):
    ob = _fbhead()
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 0, 5000
    assert bpy.ops.shapespace.retarget(filepath=CSV, method="copy") == {"FINISHED"}
    assert (scene.frame_start, scene.frame_end) == (0, 5000)
    assert retarget.last_report(ob).scene_range_extended is False


def _cli(*args):
    proc = subprocess.run([sys.executable, RUN_CLI, *args], capture_output=True, text=True, timeout=900,
                          env=dict(os.environ))
    return proc.returncode, proc.stdout, proc.stderr


def _clipping_blend(tmp_path):
    """FBHead with JawOpen and both smiles capped at 0.3, so the capture clips at known frames."""
    ob = _fbhead()
    for name in ("JawOpen", "MouthSmileLeft", "MouthSmileRight"):
        ob.data.shape_keys.key_blocks[name].slider_max = 0.3
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 100
    path = str(tmp_path / "capped.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path, copy=True)
    frames, w = _capture_frames()
    names = read_live_link_csv(CSV).names
    mapping = retarget.channel_mapping(ob, names, shapekeys.read_blendshape_model(ob).names)
    model = shapekeys.read_blendshape_model(ob)
    clipped = np.zeros(frames.size, bool)
    for i, j, gain, offset in mapping:
        v = gain * w[:, i] + offset
        clipped |= (v < model.slider_min[j] - 1e-9) | (v > model.slider_max[j] + 1e-9)
    return path, frames, clipped


def _runs_to_frames(runs):
    return [f for a, b in runs for f in range(a, b + 1)]


def test_batch_report_lists_clipped_ranges_and_saves_the_widened_range(tmp_path):
    path, frames, clipped = _clipping_blend(tmp_path)
    assert 0 < clipped.sum() < frames.size
    out, report = tmp_path / "out.blend", tmp_path / "report.json"
    code, stdout, err = _cli(path, "--", "retarget", "--source", CSV, "--method", "copy", "--out", str(out),
                             "--report", str(report))
    assert code == 0, err
    result = json.loads(report.read_text())["results"][0]
    assert _runs_to_frames(result["clipped_frames"]) == [int(f) for f in frames[clipped]]
    assert result["clipping_frames"] == int(clipped.sum())
    assert result["frame_range"] == [int(frames[0]), int(frames[-1])] and result["scene_range_extended"]
    bpy.ops.wm.open_mainfile(filepath=str(out))
    scene = bpy.context.scene
    action = bpy.data.actions[result["action"]]
    first, last = actions.frame_range(action)
    assert scene.frame_start <= first and scene.frame_end >= last == frames[-1]
    assert (scene.frame_start, scene.frame_end) == (1, int(frames[-1]))
    # the dry run reports the same, and --keep-scene-range leaves the saved range alone
    code, stdout, err = _cli(path, "--", "retarget", "--source", CSV, "--method", "copy", "--dry-run")
    assert code == 0 and json.loads(stdout)["results"][0]["clipped_frames"] == result["clipped_frames"]
    kept = tmp_path / "kept.blend"
    code, stdout, err = _cli(path, "--", "retarget", "--source", CSV, "--method", "copy", "--keep-scene-range",
                             "--out", str(kept))
    assert code == 0, err
    assert json.loads(stdout)["results"][0]["scene_range_extended"] is False
    bpy.ops.wm.open_mainfile(filepath=str(kept))
    assert (bpy.context.scene.frame_start, bpy.context.scene.frame_end) == (1, 100)


def test_help_documents_keep_scene_range():
    code, stdout, err = _cli("--", "retarget", "--help")
    assert code == 0
    assert "--keep-scene-range" in stdout and "clipped_frames" in stdout


def test_operator_report_names_clipped_frames(registered, tmp_path):
    path, frames, clipped = _clipping_blend(tmp_path)
    bpy.ops.wm.open_mainfile(filepath=path)
    ob = bpy.data.objects["FBHead"]
    bpy.context.view_layer.objects.active = ob
    assert bpy.ops.shapespace.retarget(filepath=CSV, method="copy") == {"FINISHED"}
    rep = retarget.last_report(ob)                          # what the panel shows, kept in the file
    assert _runs_to_frames(rep.clipped_frames) == [int(f) for f in frames[clipped]]
    from shapespace.core.retarget.report import format_ranges
    from shapespace.operators.retarget.run_retarget import result_message
    assert f"beyond the slider ranges at {format_ranges(rep.clipped_frames)}" in result_message(rep)


def test_batch_progress_lines_go_to_stderr(capsys):
    from shapespace.cli.commands import _ProgressLines
    lines = _ProgressLines("take.csv", interval=0.0)
    for f in (0.05, 0.12, 0.18, 0.35, 0.9, 1.0):
        lines(f)
    out, err = capsys.readouterr()
    assert out == ""
    assert [ln.split(" (")[0] for ln in err.splitlines()] == [
        "shapespace: take.csv: 12 %", "shapespace: take.csv: 35 %", "shapespace: take.csv: 90 %"]


def test_invoke_without_a_window_runs_in_one_go(registered):
    """INVOKE_DEFAULT with no window (background, scripts) has no event loop to poll from: it runs like
    EXEC_DEFAULT and writes the result at once."""
    ob = _fbhead()
    assert bpy.ops.shapespace.retarget("INVOKE_DEFAULT", filepath=CSV, method="copy") == {"FINISHED"}
    assert retarget.last_report(ob).action == actions.active_action(ob.data.shape_keys).name
