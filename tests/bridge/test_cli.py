"""``shapespace info`` through tools/run_cli.py (the same handler Blender's --command runs).

Command-line hardening (#10): outputs checked before any work, inputs never overwritten, one-line errors, stdout
only JSON, every batch result kept in the saved file."""
import hashlib
import json
import os
import shutil
import subprocess
import sys

import pytest

from blender_support import bpy
from support import ASSETS, ROOT, shared

RUN_CLI = os.path.join(ROOT, "tools", "run_cli.py")


def run_cli(*args):
    proc = subprocess.run([sys.executable, RUN_CLI, *args], capture_output=True, text=True, timeout=300,
                          env=dict(os.environ))
    return proc.returncode, proc.stdout, proc.stderr


def _json(stdout):
    return json.loads(stdout[stdout.index("{"):])  # Blender may log a line before the JSON


def _error_lines(stderr):
    return [ln for ln in stderr.splitlines() if ln.startswith("shapespace: error:")]


def test_info_on_vendored_facecap():
    code, out, err = run_cli(os.path.join(ASSETS, "facecap", "facecap_decoded.glb"), "--", "info")
    assert code == 0, err
    rep = _json(out)
    faces = {m["object"]: m for m in rep["shape_key_meshes"]}
    head = faces["Mesh_2"]
    assert head["vertices"] == 2694 and head["shape_keys"] == 52 and head["rank"] == 51
    assert head["arkit_channels"] == 52
    assert any(i["code"] == "empty_target" and "tongueOut" in i["message"] for i in head["issues"])
    # the glTF importer names actions differently across Blender versions: find it by content
    shape = next(a for a in rep["actions"] if a["shape_key_curves"])
    assert head["animated_by"] == shape["name"]
    assert shape["shape_key_curves"] == 52 and shape["fractional_keys"]
    assert shape["frame_range"][0] == pytest.approx(1.14, abs=1e-3)


def test_info_on_blend_and_out_file(tmp_path):
    out_file = tmp_path / "info.json"
    code, out, err = run_cli(shared("llf_fbhead", "Live_Link_Face.blend"), "--", "info", "--out", str(out_file))
    assert code == 0, err
    rep = json.loads(out_file.read_text())
    assert rep["scene"]["fps"] == 30.0
    head = rep["shape_key_meshes"][0]
    assert head["object"] == "FBHead" and head["shape_keys"] == 51 and head["arkit_channels"] == 51


def test_info_on_skinned_character_lists_armature_and_action():
    code, out, err = run_cli("--", "info", shared("cesium_man", "CesiumMan.glb"))
    assert code == 0, err
    rep = _json(out)
    assert rep["armatures"][0]["bones"] == 19
    assert rep["skinned_meshes"][0]["object"] == "Cesium_Man"
    assert not any(m["object"] == "Icosphere" for m in rep["shape_key_meshes"] + rep["skinned_meshes"])
    assert rep["actions"][0]["bone_curves"] > 0


def test_missing_file_is_one_line_and_nonzero(tmp_path):
    missing = str(tmp_path / "nope.blend")
    code, out, err = run_cli(missing, "--", "info")
    assert code == 1 and out == ""
    lines = _error_lines(err)
    assert lines == [f"shapespace: error: file not found: {missing}"]


@pytest.mark.parametrize("suffix", [".blend", ".glb"])
def test_corrupt_file_is_one_line_and_nonzero(tmp_path, suffix):
    bad = tmp_path / f"corrupt{suffix}"
    bad.write_bytes(b"this is not a " + suffix.encode() + b" file" * 50)
    code, out, err = run_cli("--", "info", str(bad))
    assert code == 1
    lines = _error_lines(err)
    assert len(lines) == 1 and lines[0].startswith(f"shapespace: error: cannot read {bad}")


@pytest.mark.one_blender
def test_unsupported_type_and_usage_errors(tmp_path):
    other = tmp_path / "face.obj"
    other.write_text("v 0 0 0\n")
    code, _, err = run_cli("--", "info", str(other))
    assert code == 1 and "unsupported file type .obj" in _error_lines(err)[0]
    code, _, err = run_cli("--", "bogus")
    assert code == 2 and len(_error_lines(err)) == 1


def test_bvh_is_an_armature_with_an_action():
    code, out, err = run_cli("--", "info", shared("cmu_mocap", "131_01.bvh"))
    assert code == 0, err
    rep = _json(out)
    assert rep["armatures"][0]["bones"] == 31 and rep["actions"][0]["bone_curves"] == 96


def test_file_without_rigs_is_an_error(tmp_path):
    empty = tmp_path / "empty.blend"
    script = ("import bpy; bpy.ops.wm.read_factory_settings(use_empty=True); "
              f"bpy.ops.wm.save_as_mainfile(filepath={str(empty)!r})")
    subprocess.run([sys.executable, "-c", script], check=True, capture_output=True, env=dict(os.environ))
    code, out, err = run_cli(str(empty), "--", "info")
    assert code == 1
    assert _error_lines(err) == ["shapespace: error: no meshes with shape keys, armatures or skinned meshes found"]


CSV = os.path.join(ASSETS, "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")
BLEND = os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend")


def cli(*args, python=None):
    proc = subprocess.run([python or sys.executable, RUN_CLI, *map(str, args)], capture_output=True, text=True,
                          timeout=600, env=dict(os.environ))
    return proc.returncode, proc.stdout, proc.stderr


def errors(stderr):
    return [ln for ln in stderr.splitlines() if ln.startswith("shapespace: error:")]


def digest(path):
    return hashlib.sha256(open(path, "rb").read()).hexdigest()


@pytest.fixture
def shot(tmp_path):
    """A copy of the FBHead scene and of its take, as a user's files."""
    blend, take = tmp_path / "shot.blend", tmp_path / "take.csv"
    shutil.copy(BLEND, blend)
    shutil.copy(CSV, take)
    return blend, take


def _saved_actions(path):
    bpy.ops.wm.open_mainfile(filepath=str(path))
    return {a.name: a.use_fake_user for a in bpy.data.actions}


# ----------------------------------------------------------------------------------------- r04
def test_batch_out_keeps_every_result(shot, tmp_path):
    blend, take = shot
    takes = []
    for k in range(3):
        takes.append(tmp_path / f"take{k}.csv")
        shutil.copy(take, takes[-1])
    out, report = tmp_path / "retargeted.blend", tmp_path / "report.json"
    code, stdout, err = cli(blend, "--", "retarget", *sum((["--source", t] for t in takes), []), "--method", "copy",
                            "--out", out, "--report", report)
    assert code == 0, err
    assert stdout == ""
    rep = json.loads(report.read_text())
    names = [r["action"] for r in rep["results"]]
    assert rep["saved"] == str(out) and len(set(names)) == 3
    assert _saved_actions(out) == {name: True for name in names}
    assert [ln for ln in err.splitlines() if ln.startswith("shapespace: [")] == [
        f"shapespace: [{k + 1}/3] {t} → FBHead (copy)" for k, t in enumerate(takes)]


# ----------------------------------------------------------------------------------------- r12
@pytest.mark.one_blender
def test_outputs_never_overwrite_inputs(shot, tmp_path):
    blend, take = shot
    kept = digest(blend), digest(take)
    code, _, err = cli(blend, "--", "info", "--out", blend)
    assert code == 1 and errors(err) == [f"shapespace: error: --out {blend}: would overwrite the input {blend}"]
    code, _, err = cli(blend, "--", "retarget", "--source", take, "--method", "copy", "--dry-run", "--report", take)
    assert code == 1 and errors(err) == [f"shapespace: error: --report {take}: would overwrite the input {take}"]
    code, _, err = cli(blend, "--", "retarget", "--source", take, "--method", "copy", "--out", blend)
    assert code == 1 and "would overwrite the input" in errors(err)[0] and "--overwrite" in errors(err)[0]
    code, _, err = cli(blend, "--", "retarget", "--source", take, "--method", "copy", "--out", take, "--overwrite")
    assert code == 1 and "would overwrite the input" in errors(err)[0]
    assert (digest(blend), digest(take)) == kept and not os.path.exists(f"{blend}1")
    # saving into the opened .blend on purpose: --overwrite (Blender keeps the old one as .blend1)
    code, _, err = cli(blend, "--", "retarget", "--source", take, "--method", "copy", "--out", blend, "--overwrite",
                       "--report", tmp_path / "r.json")
    assert code == 0, err
    assert digest(f"{blend}1") == kept[0] and "FBHead_take" in _saved_actions(blend)


@pytest.mark.one_blender
def test_report_onto_a_file_of_another_kind_needs_overwrite(shot, tmp_path):
    blend, take = shot
    notes = tmp_path / "notes.txt"
    notes.write_text("my notes\n")
    args = [blend, "--", "retarget", "--source", take, "--method", "copy", "--dry-run", "--report", notes]
    code, _, err = cli(*args)
    assert code == 1 and errors(err) == [f"shapespace: error: --report {notes}: exists and is not a JSON report; "
                                         "give --overwrite to replace it"]
    assert notes.read_text() == "my notes\n"
    code, _, err = cli(*args, "--overwrite")
    assert code == 0, err
    assert json.loads(notes.read_text())["results"][0]["ok"]
    code, _, err = cli(*args)                             # now a JSON report: replaced without a flag
    assert code == 0, err


@pytest.mark.one_blender
def test_retarget_needs_out_or_dry_run(shot):
    blend, take = shot
    code, out, err = cli(blend, "--", "retarget", "--source", take, "--method", "copy")
    assert code == 2 and out == ""
    assert len(errors(err)) == 1 and "--out" in errors(err)[0] and "--dry-run" in errors(err)[0]
    code, out, err = cli(blend, "--", "retarget", "--source", take, "--method", "copy", "--dry-run")
    assert code == 0, err
    assert json.loads(out)["saved"] is None                  # stdout is the JSON alone


# ----------------------------------------------------------------------------------------- r16
@pytest.mark.one_blender
def test_unwritable_destinations_fail_before_any_work(shot, tmp_path):
    blend, take = shot
    missing = tmp_path / "no" / "dir"
    ok = tmp_path / "ok.blend"
    for args in (["info", "--out", missing / "info.json"],
                 ["retarget", "--source", take, "--method", "copy", "--out", missing / "out.blend"],
                 ["retarget", "--source", take, "--method", "copy", "--out", ok, "--report", missing / "r.json"],
                 ["retarget", "--source", take, "--method", "copy", "--out", tmp_path,
                  "--report", tmp_path / "r.json"]):
        code, out, err = cli(blend, "--", *args)
        assert code == 1 and out == "" and "Traceback" not in err, err
        assert len(errors(err)) == 1 and "[1/1]" not in err, err      # refused before the first source
    assert not ok.exists() and not (tmp_path / "r.json").exists()


@pytest.mark.skipif(not os.path.exists("/proc/version"), reason="needs /proc")
def test_write_failure_is_one_line():
    code, out, err = cli(BLEND, "--", "info", "--out", "/proc/version", "--overwrite")
    assert code == 1 and out == "" and "Traceback" not in err
    assert len(errors(err)) == 1 and errors(err)[0].startswith("shapespace: error: --out /proc/version: ")


# ----------------------------------------------------------------------------------------- r13
def test_one_bad_take_does_not_abort_the_batch(shot, tmp_path):
    blend, take = shot
    bad = tmp_path / "stray_quote.csv"
    bad.write_text('"' + take.read_text() * 500)
    out, report = tmp_path / "out.blend", tmp_path / "report.json"
    code, _, err = cli(blend, "--", "retarget", "--source", take, "--source", bad, "--source", tmp_path / "take.csv",
                       "--method", "copy", "--out", out, "--report", report)
    assert code == 1 and "Traceback" not in err
    assert errors(err) == [f"shapespace: error: {bad}: line 1: not a readable CSV row (field larger than field "
                           "limit (131072); a stray quote?)"]
    rep = json.loads(report.read_text())
    assert [r["ok"] for r in rep["results"]] == [True, False, True]
    assert set(_saved_actions(out)) == {r["action"] for r in rep["results"] if r["ok"]}


# ----------------------------------------------------------------------------------------- r24
@pytest.mark.one_blender
def test_bad_flags_are_refused_naming_the_flag(shot):
    blend, take = shot
    for flag, value in (("--lam", "nan"), ("--lam", "0"), ("--key-tolerance", "-1"), ("--key-tolerance", "nan")):
        code, _, err = cli(blend, "--", "retarget", "--source", take, "--dry-run", flag, value)
        assert code == 2 and len(errors(err)) == 1 and f"argument {flag}: must be a" in errors(err)[0]


@pytest.mark.parametrize("name, data", [("bad.bvh", b"HIERARCHY\nROOT Hips\n{\n OFFSET 0 0\n"),
                                        ("bad.fbx", bytes(range(256)) * 20)], ids=["bvh", "fbx"])
def test_garbage_import_is_one_line_without_traceback(tmp_path, name, data):
    path = tmp_path / name
    path.write_bytes(data)
    code, out, err = cli(path, "--", "info")
    assert code == 1 and out == ""
    assert err.strip().splitlines() == errors(err) and len(errors(err)) == 1
    assert errors(err)[0].startswith(f"shapespace: error: cannot read {path}: ") and "Location:" not in err


def test_file_without_shape_key_mesh_says_so():
    glb = os.path.join(ASSETS, "cesium_man", "CesiumMan.glb")
    code, _, err = cli(glb, "--", "retarget", "--source", CSV, "--dry-run")
    assert code == 1 and errors(err) == [f"shapespace: error: no mesh with shape keys in {glb}: nothing to "
                                         "retarget onto"]


def test_short_take_and_non_files_are_one_line_each(shot, tmp_path):
    blend, take = shot
    short = tmp_path / "short.csv"
    short.write_text("Timecode,JawOpen\n" + "".join(f"00:00:00:00.{k}00,0.{k}\n" for k in range(3)))
    folder = tmp_path / "dir.csv"
    folder.mkdir()
    fifo = tmp_path / "fifo.csv"
    os.mkfifo(fifo)
    code, out, err = cli(blend, "--", "retarget", "--source", short, "--source", folder, "--source", fifo,
                         "--method", "copy", "--dry-run")
    assert code == 1 and "nan" not in out.lower()
    assert errors(err) == [
        f"shapespace: error: {short}: the take lasts 0.003 s, 1 frame(s) at 30 fps; at least 3 are needed",
        f"shapespace: error: {folder}: is a directory, not a CSV file",
        f"shapespace: error: {fifo}: is not a regular file (a FIFO, socket or device); give a CSV file"]
    assert [r["ok"] for r in json.loads(out)["results"]] == [False, False, False]


def test_bad_timecode_names_file_and_line(shot, tmp_path):
    blend, take = shot
    lines = take.read_text().splitlines()
    lines[5] = "99999:00:00:00.000" + lines[5][lines[5].index(","):]
    bad = tmp_path / "bad_hour.csv"
    bad.write_text("\n".join(lines) + "\n")
    code, _, err = cli(blend, "--", "retarget", "--source", bad, "--method", "copy", "--dry-run")
    assert code == 1 and errors(err) == [f"shapespace: error: {bad}: line 6: timecode '99999:00:00:00.000' is out "
                                         "of range (HH 0–23, MM and SS 0–59, FF below 60)"]


# ----------------------------------------------------------------------------------------- stdout, plain python
def test_stdout_carries_only_the_json():
    code, out, err = cli(BLEND, "--", "info")
    assert code == 0, err
    assert json.loads(out)["shape_key_meshes"][0]["object"] == "FBHead"
    assert "Read blend" in err


@pytest.mark.skipif(not os.path.isfile(os.path.join(ROOT, ".venv", "core", "bin", "python")),
                    reason="needs a python without bpy (.venv/core)")
def test_run_cli_works_from_a_python_without_bpy():
    code, out, err = cli(BLEND, "--", "info", python=os.path.join(ROOT, ".venv", "core", "bin", "python"))
    assert code == 0, err
    assert json.loads(out)["shape_key_meshes"][0]["object"] == "FBHead"


# ----------------------------------------------------------------------------------------- #26.10
def test_source_rig_in_a_take_file_says_it_is_not_a_rig_file(shot):
    blend, take = shot
    code, _, err = cli(blend, "--", "transfer", "--source-rig", f"{take}:FBHead", "--dry-run")
    assert code == 2 and errors(err) == [f"shapespace: error: --source-rig {take}:FBHead: {take} is not a rig "
                                         "file; give the .blend holding the rig (FILE.blend:OBJECT)"]


def test_transfer_source_that_is_the_only_mesh_names_it(shot):
    blend, _ = shot
    code, _, err = cli(blend, "--", "transfer", "--source-rig", "FBHead", "--dry-run")
    assert code == 1 and errors(err) == ["shapespace: error: no mesh to transfer onto: the only mesh is the source "
                                         "rig 'FBHead'; open the target's .blend (or --target) or add the target "
                                         "mesh"]


def test_missing_key_pose_action_is_said_not_to_exist(shot):
    blend, take = shot
    code, _, err = cli(blend, "--", "retarget", "--source", take, "--method", "learned", "--key-poses", "NoSuch",
                       "--dry-run")
    assert code == 1 and errors(err) == [f"shapespace: error: {take}: key-pose action 'NoSuch' does not exist in "
                                         "this file"]
