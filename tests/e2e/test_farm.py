"""Farm jobs (tools/farm/): the Open Job Description template under `openjd check` / `openjd run`, and the
Flamenco job type through a node harness of Flamenco's job-compiler API — both on the shipped Live Link Face
recording split into two takes, against the shipped FBHead rig, compared with the batch command.

Here "blender" is ``python tools/run_cli.py`` (no Blender binary): it takes Blender's own command line
(``-b FILE --command shapespace …`` and ``--command extension install-file …``), runs Blender's extension
installer, and uses the installed extension when there is one, as Blender would.
"""
import json
import os
import re
import shlex
import shutil
import subprocess
import sys

import numpy as np
import pytest

from support import ASSETS, ROOT

bpy = pytest.importorskip("bpy")

FARM = os.path.join(ROOT, "tools", "farm")
TEMPLATE = os.path.join(FARM, "shapespace_retarget.openjd.yaml")
JOB_TYPE = os.path.join(FARM, "shapespace_retarget.js")
HARNESS = os.path.join(FARM, "flamenco_harness.js")
RIG = os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend")
CSV = os.path.join(ASSETS, "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")
BLENDER = [sys.executable, os.path.join(ROOT, "tools", "run_cli.py")]
OPENJD = os.path.join(os.path.dirname(sys.executable), "openjd")
if not os.path.exists(OPENJD):      # the job definitions are checked once, in the bpy 5.0 run (requirements/bpy50.txt)
    pytest.skip("openjd-cli is installed only in the bpy 5.0 test environment", allow_module_level=True)
NODE = shutil.which("node")
SETTINGS = ["--method", "spacetime", "--key-tolerance", "0.01"]


def batch_args(takes, out, report):
    """The batch command (after the executable): every take in one Blender session."""
    sources = [a for t in takes for a in ("--source", t)]
    return ["-b", RIG, "--command", "shapespace", "retarget", *sources, *SETTINGS, "--out", out, "--report", report]


def take_args(take, out_dir):
    """The batch command for one take, writing <stem>.blend and <stem>.json."""
    stem = os.path.splitext(os.path.basename(take))[0]
    return batch_args([take], os.path.join(out_dir, f"{stem}.blend"), os.path.join(out_dir, f"{stem}.json"))


def run(cmd, env=None, timeout=900):
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env or dict(os.environ))
    return proc.returncode, proc.stdout, proc.stderr


@pytest.fixture(scope="module")
def takes(tmp_path_factory):
    """The shipped recording as two takes (first and second half of its rows)."""
    folder = tmp_path_factory.mktemp("takes")
    with open(CSV, encoding="utf-8") as fh:
        header, *rows = fh.read().splitlines()
    half = len(rows) // 2
    paths = []
    for i, part in enumerate((rows[:half], rows[half:]), start=1):
        path = folder / f"take{i}.csv"
        path.write_text("\n".join([header, *part]) + "\n")
        paths.append(str(path))
    return paths


@pytest.fixture(scope="module")
def batch(takes, tmp_path_factory):
    """The batch command's actions: {action name: {data path: keys (m, 2)}}."""
    out = tmp_path_factory.mktemp("batch")
    code, _, err = run([*BLENDER, *batch_args(takes, str(out / "batch.blend"), str(out / "batch.json"))])
    assert code == 0, err[-2000:]
    return actions_in(str(out / "batch.blend"))


@pytest.fixture(scope="module")
def extension_zip(tmp_path_factory):
    """ShapeSpace as an extension zip, built by Blender's own extension builder (the repository's add-on files;
    no SciPy wheel: this Python has SciPy)."""
    import build  # tools/build.py
    work = tmp_path_factory.mktemp("zip")
    src = work / "shapespace"
    src.mkdir()
    for name in ("core", "bridge", "operators", "panels", "properties", "ui", "cli"):
        shutil.copytree(os.path.join(ROOT, name), src / name, ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("__init__.py", "LICENSE"):
        shutil.copy(os.path.join(ROOT, name), src / name)
    with open(os.path.join(ROOT, "blender_manifest.toml"), encoding="utf-8") as fh:
        manifest = fh.read()
    manifest = re.sub(r"(?ms)^wheels = \[.*?^\]\n", "", manifest)
    manifest = re.sub(r"(?m)^platforms = .*\n", "", manifest)
    (src / "blender_manifest.toml").write_text(manifest)
    code, out, err = run([sys.executable, build.blender_ext_script(), "build", "--source-dir", str(src),
                          "--output-dir", str(work)])
    assert code == 0, out + err
    (zip_path,) = [p for p in work.iterdir() if p.suffix == ".zip"]
    return str(zip_path)


def actions_in(blend):
    """Every action of a .blend as {name: {data path: keys (m, 2)}} (appended into this session, then removed)."""
    with bpy.data.libraries.load(blend) as (src, dst):
        dst.actions = list(src.actions)
    out = {}
    for act in dst.actions:
        curves = {}
        for layer in act.layers:
            for strip in layer.strips:
                for bag in strip.channelbags:
                    for fc in bag.fcurves:
                        co = np.empty(len(fc.keyframe_points) * 2, np.float32)
                        fc.keyframe_points.foreach_get("co", co)
                        curves[fc.data_path] = co.reshape(-1, 2)
        out[act.name] = curves
        bpy.data.actions.remove(act)
    return out


def assert_same_actions(got, want, names):
    for name in names:
        assert name in got and name in want, (name, sorted(got), sorted(want))
        assert sorted(got[name]) == sorted(want[name])
        for path, keys in want[name].items():
            np.testing.assert_array_equal(got[name][path], keys, err_msg=f"{name} {path}")


def user_env(folder):
    """A fresh Blender user folder for the 'worker' (the extension is installed there)."""
    os.makedirs(folder, exist_ok=True)
    return dict(os.environ, BLENDER_USER_RESOURCES=str(folder))


# -- Open Job Description -----------------------------------------------------------------------------------------

def openjd(*args, env=None):
    return run([OPENJD, *args], env=env)


def job_params(takes, out_dir, zip_path=""):
    params = {"Rig": RIG, "Takes": takes, "OutputDir": str(out_dir), "Method": "spacetime", "KeyTolerance": 0.01,
              "Blender": shlex.join(BLENDER), "ExtensionZip": zip_path}
    return ["-p", json.dumps(params)]


def test_openjd_check_validates_the_template():
    code, out, err = openjd("check", TEMPLATE)
    assert code == 0 and "passes validation" in out, out + err


def test_openjd_run_two_takes_installs_and_matches_the_batch(takes, batch, extension_zip, tmp_path):
    out_dir = tmp_path / "out"
    env = user_env(tmp_path / "worker")
    code, out, err = openjd("run", TEMPLATE, *job_params(takes, out_dir, extension_zip), env=env)
    assert code == 0, (out + err)[-4000:]
    # ShapeSpace was installed into the worker's Blender with Blender's own `extension install-file`
    assert os.path.isfile(tmp_path / "worker" / "extensions" / "user_default" / "shapespace" / "__init__.py")
    assert "Installed" in out or "Installed" in err
    merged = json.loads((out_dir / "merged.json").read_text())
    assert merged["ok"] and merged["succeeded"] == takes and merged["takes"] == 2
    got = {}
    for take in takes:
        got.update(actions_in(str(out_dir / (os.path.splitext(os.path.basename(take))[0] + ".blend"))))
    assert_same_actions(got, batch, ["FBHead_take1", "FBHead_take2"])


def test_openjd_missing_take_fails_alone_and_the_merge_names_it(takes, tmp_path):
    """As on a farm, each task runs in its own session: the missing take's task fails, the other finishes,
    and the merge task (run on its own) reports the failure and exits 1."""
    out_dir = tmp_path / "out"
    missing = str(tmp_path / "gone.csv")
    batch_takes = [takes[0], missing]
    results = {}
    for take in batch_takes:
        results[take] = openjd("run", TEMPLATE, *job_params(batch_takes, out_dir), "--step", "Retarget",
                               "--task-param", f"Take={take}")
    assert results[takes[0]][0] == 0, results[takes[0]][1][-3000:]
    assert results[missing][0] != 0
    assert (out_dir / "take1.blend").exists() and not (out_dir / "gone.blend").exists()
    code, out, err = openjd("run", TEMPLATE, *job_params(batch_takes, out_dir), "--step", "MergeReports",
                            "--no-run-dependencies")
    assert code != 0
    merged = json.loads((out_dir / "merged.json").read_text())
    assert merged["succeeded"] == [takes[0]] and [f["take"] for f in merged["failed"]] == [missing]
    assert "file not found" in merged["failed"][0]["error"]
    assert f"shapespace: error: {missing}:" in out + err


def test_openjd_blender_parameter_is_words_never_shell_and_flag_takes_are_refused(takes, tmp_path):
    """#26.13: the Blender parameter is split into words, never run through bash (a ``$( )`` in it runs nothing);
    a take shaped like a flag is refused by the take's task and by the merge."""
    mark = tmp_path / "ran"
    params = {"Rig": RIG, "Takes": [takes[0]], "OutputDir": str(tmp_path / "out"),
              "Blender": f"{shlex.join(BLENDER)} $(touch {mark})"}
    openjd("run", TEMPLATE, "-p", json.dumps(params), "--step", "Retarget", "--task-param", f"Take={takes[0]}")
    assert not mark.exists()
    params = {**params, "Blender": shlex.join(BLENDER), "Takes": ["-x.csv", takes[0]]}
    for step in (["--step", "Retarget", "--task-param", "Take=-x.csv"],
                 ["--step", "MergeReports", "--no-run-dependencies"]):
        code, out, err = openjd("run", TEMPLATE, "-p", json.dumps(params), *step)
        assert code != 0 and "take '-x.csv' looks like a command-line flag: give it as a path (./-x.csv)" in out + err


# -- Flamenco ---------------------------------------------------------------------------------------------------

def compile_flamenco(tmp_path, settings):
    path = tmp_path / "settings.json"
    path.write_text(json.dumps(settings))
    code, out, err = run([NODE, HARNESS, JOB_TYPE, str(path)])
    assert code == 0, err
    return json.loads(out)


def worker_argv(cmd, blender, blender_args="-b -y"):
    """What Flamenco's worker runs for a blender-render command: {blender} (shlex-split) {blenderArgs}
    argsBefore blendfile args."""
    assert cmd["type"] == "blender-render"
    p = cmd["parameters"]
    exe = shlex.split(p["exe"].replace("{blender}", blender))
    exe_args = shlex.split(p.get("exeArgs", "").replace("{blenderArgs}", blender_args))
    return [*exe, *exe_args, *p["argsBefore"], p["blendfile"], *p["args"]]


def flamenco_settings(takes, out_dir, zip_path="", chunk_size=1):
    return {"takes": "; ".join(takes), "output_dir": str(out_dir), "blendfile": RIG, "method": "spacetime",
            "key_tolerance": 0.01, "extension_zip": zip_path, "chunk_size": chunk_size}


@pytest.mark.skipif(NODE is None, reason="node is needed for the Flamenco job type")
def test_flamenco_job_type_commands_equal_the_batch_command_and_run(takes, batch, extension_zip, tmp_path):
    out_dir = tmp_path / "out"
    compiled = compile_flamenco(tmp_path, flamenco_settings(takes, out_dir, extension_zip))
    tasks = {t["name"]: t for t in compiled["tasks"]}
    assert list(tasks) == ["retarget-take1", "retarget-take2", "merge-reports"]
    assert tasks["merge-reports"]["dependencies"] == ["retarget-take1", "retarget-take2"]
    blender = shlex.join(BLENDER)
    for take, name in zip(takes, ["retarget-take1", "retarget-take2"]):
        install, retarget = (worker_argv(c, blender) for c in tasks[name]["commands"])
        assert install[len(BLENDER):] == ["-b", "-y", RIG, "--command", "extension", "install-file", "-r",
                                          "user_default", "-e", extension_zip]
        want = take_args(take, str(out_dir))
        assert retarget[len(BLENDER):] == [want[0], "-y", *want[1:]]      # the batch command, one take
    # the commands run as a worker would: each task's commands in order, the merge after its dependencies
    env = user_env(tmp_path / "worker")
    os.makedirs(out_dir)
    for name in ["retarget-take1", "retarget-take2", "merge-reports"]:
        for cmd in tasks[name]["commands"]:
            code, out, err = run(worker_argv(cmd, blender), env=env)
            assert code == 0, (name, err[-3000:])
    assert os.path.isfile(tmp_path / "worker" / "extensions" / "user_default" / "shapespace" / "__init__.py")
    merged = json.loads((out_dir / "merged.json").read_text())
    assert merged["ok"] and merged["succeeded"] == takes
    got = {}
    for stem in ("take1", "take2"):
        got.update(actions_in(str(out_dir / f"{stem}.blend")))
    assert_same_actions(got, batch, ["FBHead_take1", "FBHead_take2"])


@pytest.mark.skipif(NODE is None, reason="node is needed for the Flamenco job type")
def test_flamenco_chunks_and_refusals(takes, tmp_path):
    compiled = compile_flamenco(tmp_path, flamenco_settings(takes, tmp_path, chunk_size=2))
    (task, merge) = compiled["tasks"]
    assert task["name"] == "retarget-take1+take2" and len(task["commands"]) == 2   # no install: none given
    assert merge["dependencies"] == [task["name"]]
    dup = flamenco_settings([takes[0], takes[0]], tmp_path)
    path = tmp_path / "dup.json"
    path.write_text(json.dumps(dup))
    code, _, err = run([NODE, HARNESS, JOB_TYPE, str(path)])
    assert code == 1 and "would both write take1.json" in err
    bad = dict(flamenco_settings(takes, tmp_path), method="magic")
    path.write_text(json.dumps(bad))
    code, _, err = run([NODE, HARNESS, JOB_TYPE, str(path)])
    assert code == 1 and "not one of" in err
    script = tmp_path / "bad.js"
    script.write_text('const JOB_TYPE = {label: "x", settings: []};\n'
                      'function compileJob(job) { job.addTask(author.Task("t", "misc").addCommand('
                      'author.Command("render-everything", {})));\n}\n')
    path.write_text("{}")
    code, _, err = run([NODE, HARNESS, str(script), str(path)])
    assert code == 1 and "no command" in err


@pytest.mark.skipif(NODE is None, reason="node is needed for the Flamenco job type")
def test_flamenco_takes_as_a_json_list_keep_semicolons_and_flag_takes_are_refused(tmp_path):
    """#26.13: a path holding ';' given in the JSON list form stays one take; a take shaped like a flag is refused
    (';' form and JSON form)."""
    odd = str(tmp_path / "shot;2" / "take;1.csv")
    compiled = compile_flamenco(tmp_path, {**flamenco_settings([], tmp_path), "takes": json.dumps([odd, "b.csv"])})
    names = [t["name"] for t in compiled["tasks"]]
    assert names == ["retarget-take;1", "retarget-b", "merge-reports"]
    (retarget,) = compiled["tasks"][0]["commands"]
    args = retarget["parameters"]["args"]
    assert args[args.index("--source") + 1] == odd
    merge_args = compiled["tasks"][2]["commands"][0]["parameters"]["args"]
    assert merge_args[merge_args.index("--takes") + 1:merge_args.index("--reports-dir")] == [odd, "b.csv"]
    path = tmp_path / "bad.json"
    for takes in ("a.csv; --overwrite", json.dumps(["a.csv", "-b"]), "[not json", f"{tmp_path}/shot;2/take.csv"):
        path.write_text(json.dumps({**flamenco_settings([], tmp_path), "takes": takes}))
        code, _, err = run([NODE, HARNESS, JOB_TYPE, str(path)])
        assert code == 1 and ("looks like a command-line flag" in err or "not a JSON list" in err
                              or f'"{tmp_path}/shot" is a path without a file name extension' in err), err


# -- head, neck and eye bones (#24) -------------------------------------------------------------------------------

BONES = ["head", "neck", "eye.L", "eye.R"]


@pytest.fixture(scope="module")
def bone_rig(tmp_path_factory):
    """The shipped FBHead rig with an armature beside it (neck → head → eyes), saved as a .blend."""
    path = tmp_path_factory.mktemp("bone_rig") / "rig.blend"
    bpy.ops.wm.open_mainfile(filepath=RIG)
    data = bpy.data.armatures.new("Rig")
    arm = bpy.data.objects.new("Rig", data)
    bpy.context.scene.collection.objects.link(arm)
    bpy.context.view_layer.objects.active = arm
    bpy.ops.object.mode_set(mode="EDIT")
    for name, head, tail, parent in (("neck", (0, 0, 1.4), (0, 0.02, 1.55), None),
                                     ("head", (0, 0.02, 1.55), (0, -0.01, 1.8), "neck"),
                                     ("eye.L", (0.03, -0.08, 1.65), (0.03, -0.1, 1.65), "head"),
                                     ("eye.R", (-0.03, -0.08, 1.65), (-0.03, -0.1, 1.65), "head")):
        eb = data.edit_bones.new(name)
        eb.head, eb.tail = head, tail
        if parent:
            eb.parent = data.edit_bones[parent]
    bpy.ops.object.mode_set(mode="OBJECT")
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return str(path)


def keyed_bones(report_path):
    (result,) = json.loads(open(report_path, encoding="utf-8").read())["results"]
    assert result["ok"], result
    return result.get("bones")


def test_openjd_bone_parameters_key_the_bones(takes, bone_rig, tmp_path):
    """HeadBone, NeckBone, LeftEyeBone, RightEyeBone, Armature reach `retarget --head-bone … --eye-bones …`;
    a bone name shaped like a flag is refused."""
    params = {"Rig": bone_rig, "Takes": takes[:1], "OutputDir": str(tmp_path), "Method": "copy", "KeyTolerance": 0,
              "Blender": shlex.join(BLENDER), "ExtensionZip": "", "HeadBone": "head", "NeckBone": "neck",
              "LeftEyeBone": "eye.L", "RightEyeBone": "eye.R", "Armature": "Rig"}
    step = ["--step", "Retarget", "--task-param", f"Take={takes[0]}"]
    code, out, err = openjd("run", TEMPLATE, "-p", json.dumps(params), *step)
    assert code == 0, (out + err)[-3000:]
    assert keyed_bones(tmp_path / "take1.json") == BONES
    code, out, err = openjd("run", TEMPLATE, "-p", json.dumps({**params, "NeckBone": "--overwrite"}), *step)
    assert code != 0 and "looks like a command-line flag" in out + err


@pytest.mark.skipif(NODE is None, reason="node is needed for the Flamenco job type")
def test_flamenco_bone_settings_key_the_bones(takes, bone_rig, tmp_path):
    settings = {**flamenco_settings(takes[:1], tmp_path), "blendfile": bone_rig, "method": "copy",
                "key_tolerance": 0.0, "head_bone": "head", "neck_bone": "neck", "neck_share": 0.5,
                "left_eye_bone": "eye.L", "right_eye_bone": "eye.R", "armature": "Rig"}
    (retarget,) = compile_flamenco(tmp_path, settings)["tasks"][0]["commands"]
    args = retarget["parameters"]["args"]
    assert args[args.index("--head-bone"):args.index("--method")] == [
        "--head-bone", "head", "--neck-bone", "neck", "--eye-bones", "eye.L", "eye.R", "--neck-share", "0.5",
        "--armature", "Rig"]
    code, out, err = run(worker_argv(retarget, shlex.join(BLENDER)))
    assert code == 0, err[-3000:]
    assert keyed_bones(tmp_path / "take1.json") == BONES
    (plain,) = compile_flamenco(tmp_path, flamenco_settings(takes[:1], tmp_path))["tasks"][0]["commands"]
    assert "--head-bone" not in plain["parameters"]["args"]          # no bone named: the rig's stored ones
    path = tmp_path / "bad.json"
    path.write_text(json.dumps({**settings, "armature": "-x"}))
    code, _, err = run([NODE, HARNESS, JOB_TYPE, str(path)])
    assert code == 1 and "looks like a command-line flag" in err
