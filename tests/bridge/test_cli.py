"""``shapespace info`` through tools/run_cli.py (the same handler Blender's --command runs)."""
import json
import os
import subprocess
import sys

import pytest

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
