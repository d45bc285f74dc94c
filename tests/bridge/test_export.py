"""Export for Engines: the operator, the command, bad input — and the user's file never changes."""
import json
import os
import stat
import subprocess
import sys
import tempfile

import numpy as np
import pytest

from blender_support import blend_fingerprint, bpy, classify_operator_call
from shapespace.bridge.export import export
from shapespace.bridge.export import roundtrip as rt
from shapespace.core.result import ShapeSpaceError
from support import ASSETS, ROOT

RUN_CLI = os.path.join(ROOT, "tools", "run_cli.py")
#: glTF exports: on bpy < 5.0 the test process must end through os._exit (see tests/bridge/conftest.py).
gltf_exits = pytest.mark.gltf_export
BLEND = os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend")
CSV = os.path.join(ASSETS, "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")


def _face(name="Face", values=(0.3, 0.7)):
    """A small mesh with two shape keys at fixed values (no animation)."""
    bpy.ops.mesh.primitive_uv_sphere_add(segments=12, ring_count=6)
    ob = bpy.context.active_object
    ob.name = name
    ob.shape_key_add(name="Basis")
    base = np.empty(len(ob.data.vertices) * 3, np.float32)
    ob.data.vertices.foreach_get("co", base)
    rng = np.random.default_rng(0)
    for k, v in enumerate(values):
        kb = ob.shape_key_add(name=f"K{k}")
        kb.data.foreach_set("co", (base + rng.normal(0, 0.05, base.size)).astype(np.float32))
        kb.value = v
    return ob


def _select(*obs):
    bpy.ops.object.select_all(action="DESELECT")
    for ob in obs:
        ob.select_set(True)
    bpy.context.view_layer.objects.active = obs[0] if obs else None


def _cli(*args):
    proc = subprocess.run([sys.executable, RUN_CLI, *args], capture_output=True, text=True, timeout=600,
                          env=dict(os.environ))
    return proc.returncode, proc.stdout, proc.stderr


def _errors(stderr):
    return [ln for ln in stderr.splitlines() if ln.startswith("shapespace: error:")]


def test_nothing_exportable_selected_is_refused(registered, tmp_path):
    bpy.ops.object.camera_add()
    _select(bpy.context.active_object)
    outcome, message = classify_operator_call("export_for_engines", {"filepath": str(tmp_path / "a.glb")})
    assert outcome == "refused" and "Select a mesh" in message
    with pytest.raises(ShapeSpaceError) as err:
        export("gltf", str(tmp_path / "a.glb"))
    assert err.value.code == "nothing_to_export" and "camera" in str(err.value).lower()
    _select()
    with pytest.raises(ShapeSpaceError) as err:
        export("gltf", str(tmp_path / "a.glb"))
    assert err.value.code == "nothing_to_export"
    assert not os.listdir(tmp_path)


@pytest.mark.parametrize("fmt", [pytest.param("gltf", marks=gltf_exits), "fbx", "abc"])
def test_shape_keys_without_animation_export_as_a_still(registered, tmp_path, fmt):
    ob = _face()
    _select(ob)
    frame = bpy.context.scene.frame_current
    before = blend_fingerprint()
    want = rt.sample_positions(["Face"], [frame])
    path = str(tmp_path / f"still{'.glb' if fmt == 'gltf' else '.' + fmt}")
    rep = export(fmt, path)
    assert blend_fingerprint() == before
    assert not rep.animated and (rep.frame_start, rep.frame_end) == (frame, frame)
    assert any("still" in n for n in rep.notes)
    imported = rt.reimport(fmt, path, 24)
    got = rt.imported_positions(["Face"], imported, [frame])
    assert rt.compare(want, got)["Face"].max() < 1e-5           # the keys' current values arrive


@pytest.mark.parametrize("where", ["missing", "read_only"])
def test_unwritable_output_is_refused_before_any_work(registered, tmp_path, where):
    ob = _face()
    _select(ob)
    if where == "missing":
        path = tmp_path / "no" / "such" / "folder" / "face.fbx"
    else:
        ro = tmp_path / "ro"
        ro.mkdir()
        os.chmod(ro, stat.S_IRUSR | stat.S_IXUSR)
        path = ro / "face.fbx"
    before = blend_fingerprint()
    try:
        with pytest.raises(ShapeSpaceError) as err:
            export("fbx", str(path))
        assert err.value.code == "unwritable" and str(path) in str(err.value)
        outcome, message = classify_operator_call("export_for_engines", {"filepath": str(path), "format": "FBX"})
        assert outcome == "cancelled" and ("does not exist" in message or "read-only" in message)
    finally:
        if where == "read_only":
            os.chmod(path.parent, stat.S_IRWXU)
    assert blend_fingerprint() == before
    assert not path.exists()


def test_an_existing_file_is_kept_when_the_export_is_refused(registered, tmp_path):
    ob = _face()
    _select(ob)
    old = tmp_path / "face.glb"
    old.write_bytes(b"previous export")
    with pytest.raises(ShapeSpaceError):
        export("gltf", str(old), frame_range=(10, 5))
    assert old.read_bytes() == b"previous export"
    assert sorted(os.listdir(tmp_path)) == ["face.glb"]            # no staging folder left behind


def test_operator_exports_and_leaves_the_file_unchanged(registered, tmp_path):
    ob = _face()
    _select(ob)
    path = tmp_path / "face.fbx"
    outcome, message = classify_operator_call("export_for_engines", {"filepath": str(path), "format": "FBX"})
    assert outcome == "finished", message
    assert path.stat().st_size > 0 and sorted(os.listdir(tmp_path)) == ["face.fbx"]


def test_linked_object_exports_and_stays_linked(registered, tmp_path):
    _face()
    lib = str(tmp_path / "lib.blend")
    bpy.ops.wm.save_as_mainfile(filepath=lib)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    with bpy.data.libraries.load(lib, link=True) as (_, dst):
        dst.objects = ["Face"]
    ob = dst.objects[0]
    bpy.context.scene.collection.objects.link(ob)
    _select(ob)
    before = blend_fingerprint()
    rep = export("fbx", str(tmp_path / "linked.fbx"))
    assert rep.objects == ["Face"] and (tmp_path / "linked.fbx").stat().st_size > 0
    assert blend_fingerprint() == before and ob.library is not None
    assert len(bpy.data.objects) == 1 and len(bpy.data.scenes) == 1


def test_edit_mode_is_refused(registered, tmp_path):
    ob = _face()
    _select(ob)
    bpy.ops.object.mode_set(mode="EDIT")
    outcome, message = classify_operator_call("export_for_engines", {"filepath": str(tmp_path / "a.glb")})
    assert outcome == "refused" and "Edit Mode" in message
    with pytest.raises(ShapeSpaceError) as err:
        export("gltf", str(tmp_path / "a.glb"))
    assert err.value.code == "mode"


def test_command_line_retarget_then_export_keeps_the_animation(tmp_path):
    """A TD's two commands: retarget the take, export the result; the FBX re-imports animated over the
    action's full range, every object named twice is exported once, and the shot file is untouched."""
    shot = tmp_path / "shot.blend"
    code, _, err = _cli(BLEND, "--", "retarget", "--source", CSV, "--method", "copy", "--out", str(shot),
                        "--report", str(tmp_path / "rt.json"))
    assert code == 0, err
    mtime = shot.stat().st_mtime_ns
    out = tmp_path / "face.fbx"
    code, stdout, err = _cli(str(shot), "--", "export", "--format", "fbx", "--out", str(out),
                             "--objects", "FBHead", "FBHead")
    assert code == 0, err
    rep = json.loads(stdout[stdout.index("{"):])
    assert rep["objects"] == ["FBHead"] and (rep["frame_start"], rep["frame_end"]) == (20, 183)
    assert any("more than once" in n for n in rep["notes"])
    assert shot.stat().st_mtime_ns == mtime
    rt.reimport("fbx", str(out), 30)
    key = next(o for o in bpy.data.objects if o.type == "MESH").data.shape_keys
    assert key.animation_data is not None and tuple(key.animation_data.action.frame_range) == (20.0, 183.0)


@pytest.mark.parametrize("args,code,text", [
    (["--format", "gltf", "--out", "X/a.fbx"], 1, "does not match"),
    (["--out", "X/a.usd"], 1, "cannot tell the export format"),
    (["--format", "fbx"], 2, "--out"),
    (["--out", "X/a.glb", "--objects", "Nobody"], 1, "no object named 'Nobody'"),
    (["--out", "X/a.glb", "--frame-range", "30", "10"], 1, "the first frame is after the last"),
    (["--out", "X/missing/a.glb"], 1, "does not exist"),
])
@pytest.mark.one_blender
def test_command_line_bad_input_is_one_line(tmp_path, args, code, text):
    args = [a.replace("X", str(tmp_path)) for a in args]
    got, out, err = _cli(BLEND, "--", "export", *args)
    assert got == code, err
    lines = _errors(err)
    assert len(lines) == 1 and text in lines[0], err
    assert not [p for p in os.listdir(tmp_path) if not p.startswith(".")]


@pytest.mark.one_blender
def test_merge_reports_command(tmp_path):
    (tmp_path / "a.json").write_text(json.dumps({"target": "FBHead", "method": "copy",
                                                 "results": [{"source": "a.csv", "ok": True}]}))
    out = tmp_path / "merged.json"
    code, _, err = _cli("--", "merge-reports", "--takes", "a.csv", "b.csv", "--reports-dir", str(tmp_path),
                        "--out", str(out))
    assert code == 1 and _errors(err) == ["shapespace: error: b.csv: no report: the task for b did not finish"]
    merged = json.loads(out.read_text())
    assert merged["succeeded"] == ["a.csv"] and not merged["ok"] and merged["takes"] == 2


@pytest.mark.one_blender
def test_export_out_and_report_on_one_file_are_refused_before_any_work(tmp_path):
    """#26.2: ``--out x.glb --report x.glb`` would leave the JSON report in place of the glTF."""
    same = tmp_path / "x.glb"
    code, out, err = _cli(BLEND, "--", "export", "--out", str(same), "--report", str(same))
    assert code == 1 and out == "" and "exported" not in err
    assert _errors(err) == [f"shapespace: error: --report {same}: is also the --out file; give two files"]
    assert not os.listdir(tmp_path)
    shot = tmp_path / "shot.blend"
    shot.write_bytes(open(BLEND, "rb").read())
    kept = shot.read_bytes()
    code, _, err = _cli(str(shot), "--", "export", "--out", str(tmp_path / "a.glb"), "--report", str(shot))
    assert code == 1 and _errors(err) == [f"shapespace: error: --report {shot}: would overwrite the input {shot}"]
    assert shot.read_bytes() == kept and not (tmp_path / "a.glb").exists()


def _take_report(path, source, ok=True):
    path.write_text(json.dumps({"target": "FBHead", "method": "copy", "results": [{"source": source, "ok": ok}]}))


@pytest.mark.one_blender
def test_merge_reports_never_overwrites_a_take_report(tmp_path):
    """#26.3: ``--out R/a.json`` is take a's own report, an input of the merge: refused, the report kept."""
    _take_report(tmp_path / "a.json", "a.csv")
    kept = (tmp_path / "a.json").read_bytes()
    code, _, err = _cli("--", "merge-reports", "--takes", "a.csv", "--reports-dir", str(tmp_path),
                        "--out", str(tmp_path / "a.json"))
    assert code == 1
    assert _errors(err) == [f"shapespace: error: --out {tmp_path / 'a.json'}: would overwrite the input "
                            f"{tmp_path / 'a.json'}"]
    assert (tmp_path / "a.json").read_bytes() == kept and sorted(os.listdir(tmp_path)) == ["a.json"]


@pytest.mark.one_blender
def test_merge_reports_messages(tmp_path):
    """#26.10: a damaged report is one line naming the damage; a missing --reports-dir is said once, up front;
    duplicate take stems are refused up front."""
    _take_report(tmp_path / "a.json", "a.csv")
    (tmp_path / "b.json").write_text('{"target": "FBHead", "results": [{"source": "b.csv", "ok"')
    (tmp_path / "c.json").write_text(json.dumps({"target": "FBHead", "results": [1, 2, 3]}))
    (tmp_path / "d.json").write_text(json.dumps({"target": "FBHead", "results": [{}, {}, {}, {}]}))
    out = tmp_path / "merged.json"
    code, _, err = _cli("--", "merge-reports", "--takes", "a.csv", "b.csv", "c.csv", "d.csv", "--reports-dir",
                        str(tmp_path), "--out", str(out))
    assert code == 1 and "Traceback" not in err and "unexpected" not in err
    assert _errors(err) == [
        f"shapespace: error: b.csv: report {tmp_path / 'b.json'} is damaged: not JSON (Expecting ':' delimiter "
        "at line 1)",
        f"shapespace: error: c.csv: report {tmp_path / 'c.json'} is damaged: result 0 has no ok true/false",
        f"shapespace: error: d.csv: report {tmp_path / 'd.json'} is damaged: result 0 has no ok true/false"]
    merged = json.loads(out.read_text())
    assert merged["succeeded"] == ["a.csv"] and [f["take"] for f in merged["failed"]] == ["b.csv", "c.csv", "d.csv"]
    gone = tmp_path / "gone"
    code, _, err = _cli("--", "merge-reports", "--takes", "a.csv", "b.csv", "c.csv", "--reports-dir", str(gone),
                        "--out", str(tmp_path / "m2.json"))
    assert code == 1 and _errors(err) == [f"shapespace: error: --reports-dir {gone}: no such folder (no take's "
                                          "report can be read)"]
    code, _, err = _cli("--", "merge-reports", "--takes", "x/a.csv", "y/a.csv", "--reports-dir", str(tmp_path),
                        "--out", str(tmp_path / "m3.json"))
    assert code == 2 and _errors(err) == ["shapespace: error: takes 'x/a.csv' and 'y/a.csv' would both write "
                                          "a.json: rename one"]
    assert not (tmp_path / "m2.json").exists() and not (tmp_path / "m3.json").exists()


@gltf_exits
def test_weights_beyond_unit_range_are_split_and_survive_a_clamping_importer(registered, tmp_path):
    """A key animated −1.36…1.72 (as baked PSD weights run on CesiumMan) leaves the glTF as two keys weighted in
    [0, 1] that add up to it; an importer that clamps weights to [0, 1] still gets the same mesh."""
    ob = _face(values=(0.0, 0.0))
    kb = ob.data.shape_keys.key_blocks["K0"]
    kb.slider_min, kb.slider_max = -2.0, 2.0
    for f, v in zip(range(1, 11), np.linspace(-1.36, 1.72, 10)):
        kb.value = float(v)
        kb.keyframe_insert("value", frame=f)
    _select(ob)
    path = str(tmp_path / "split.glb")
    rep = export("gltf", path)
    assert rep.baked[0].split == ["K0"] and rep.baked[0].shape_keys == 3
    doc, weights = rt.glb_animations(path)
    assert len(weights) and weights.min() >= 0.0 and weights.max() <= 1.0
    frames = list(range(1, 11))
    want = rt.sample_positions(["Face"], frames)
    imported = rt.reimport("gltf", path, 24)
    got = rt.imported_positions(["Face"], imported, frames)
    assert rt.compare(want, got)["Face"].max() < 1e-5
    for key in bpy.data.shape_keys:
        for block in key.key_blocks:
            block.slider_min, block.slider_max = 0.0, 1.0
    clamped = rt.imported_positions(["Face"], imported, frames)
    assert rt.compare(want, clamped)["Face"].max() < 1e-5
    names = [b.name for b in bpy.data.shape_keys[0].key_blocks]
    assert "K0" in names and "K0__neg" in names


def test_temporary_scene_name_is_free_afterwards(registered, tmp_path):
    ob = _face()
    _select(ob)
    export("abc", str(tmp_path / "a.abc"))
    assert [s.name for s in bpy.data.scenes] == ["Scene"]
    assert not [d for d in os.listdir(tempfile.gettempdir()) if d.startswith("shapespace-export-")
                and os.path.getmtime(os.path.join(tempfile.gettempdir(), d)) > (tmp_path.stat().st_mtime - 1)]
