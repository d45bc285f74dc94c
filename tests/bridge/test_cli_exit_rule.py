"""One exit rule for every subcommand (issue #23 item 4): 0 done (ok or warnings), 1 any report failed or did
not converge / bad input, 2 usage — through tools/run_cli.py, the handler Blender's ``--command`` runs.
(``retarget`` and ``transfer`` are tested with their capabilities.)"""
import json
import os
import subprocess
import sys

import pytest

from support import ASSETS, ROOT

RUN_CLI = os.path.join(ROOT, "tools", "run_cli.py")
BLEND = os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend")


def _cli(*args):
    proc = subprocess.run([sys.executable, RUN_CLI, *args], capture_output=True, text=True, timeout=600,
                          env=dict(os.environ))
    return proc.returncode, proc.stdout, proc.stderr


def _errors(stderr):
    return [ln for ln in stderr.splitlines() if ln.startswith("shapespace: error:")]


def _take_report(path, *results):
    path.write_text(json.dumps({"target": "FBHead", "method": "spacetime", "results": list(results)}))


@pytest.mark.one_blender
def test_help_states_the_exit_rule():
    code, out, _ = _cli("--", "--help")
    assert code == 0
    assert "Exit code (every subcommand): 0 done" in out and "2 usage" in out


@pytest.mark.parametrize("args", [
    ["info", "--no-such-flag"],
    ["export"],                                                   # --out is required
    ["export", "--out", "a.glb", "--frame-range", "1"],           # two frames needed
    ["merge-reports", "--reports-dir", "."],                      # --takes and --out are required
    ["no-such-command"],
])
@pytest.mark.one_blender
def test_usage_errors_exit_2(args):
    code, out, err = _cli("--", *args)
    assert code == 2 and out == "", err
    assert len(_errors(err)) == 1, err


def test_info_exits_0_when_done_and_1_on_a_file_it_cannot_describe(tmp_path):
    code, out, err = _cli(BLEND, "--", "info")
    assert code == 0, err
    assert json.loads(out[out.index("{"):])["status"] == "ok"
    missing = tmp_path / "nope.blend"
    code, out, err = _cli("--", "info", str(missing))
    assert code == 1 and out == "" and _errors(err) == [f"shapespace: error: file not found: {missing}"]


def test_info_on_a_capture_reports_its_status(tmp_path):
    csv = os.path.join(ASSETS, "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")
    code, out, err = _cli("--", "info", csv)
    assert code == 0, err
    rep = json.loads(out[out.index("{"):])
    assert rep["file"] == csv and rep["status"] == ("warning" if rep["issues"] else "ok")


def test_export_exits_0_when_done_and_1_on_a_failed_export(tmp_path):
    out_file = tmp_path / "face.fbx"
    code, out, err = _cli(BLEND, "--", "export", "--out", str(out_file), "--objects", "FBHead", "FBHead")
    assert code == 0, err
    rep = json.loads(out[out.index("{"):])
    assert out_file.is_file() and rep["notes"] and rep["status"] == "warning"    # "given more than once"
    code, out, err = _cli(BLEND, "--", "export", "--out", str(tmp_path / "b.fbx"), "--objects", "Nobody")
    assert code == 1 and out == "" and len(_errors(err)) == 1
    assert not (tmp_path / "b.fbx").exists()


@pytest.mark.one_blender
def test_merge_reports_exit_0_only_when_every_take_is_ok(tmp_path):
    _take_report(tmp_path / "a.json", {"source": "a.csv", "ok": True, "converged": True})
    _take_report(tmp_path / "b.json", {"source": "b.csv", "ok": True, "status": "warning"})
    out = tmp_path / "merged.json"
    code, _, err = _cli("--", "merge-reports", "--takes", "a.csv", "b.csv", "--reports-dir", str(tmp_path),
                        "--out", str(out))
    assert code == 0 and not _errors(err), err
    merged = json.loads(out.read_text())
    assert merged["ok"] and merged["status"] == "warning"


@pytest.mark.one_blender
def test_merge_reports_exit_1_when_a_take_failed(tmp_path):
    _take_report(tmp_path / "a.json", {"source": "a.csv", "ok": True})
    _take_report(tmp_path / "b.json", {"source": "b.csv", "ok": False, "error": "b.csv: no channels"})
    out = tmp_path / "merged.json"
    code, _, err = _cli("--", "merge-reports", "--takes", "a.csv", "b.csv", "--reports-dir", str(tmp_path),
                        "--out", str(out))
    assert code == 1 and _errors(err) == ["shapespace: error: b.csv: b.csv: no channels"]
    merged = json.loads(out.read_text())
    assert not merged["ok"] and merged["status"] == "failed" and merged["succeeded"] == ["a.csv"]


@pytest.mark.one_blender
def test_merge_reports_exit_1_when_a_take_did_not_converge(tmp_path):
    """A fit that stopped at its iteration limit is never reported as done (it used to exit 0)."""
    _take_report(tmp_path / "a.json", {"source": "a.csv", "ok": True, "converged": True})
    _take_report(tmp_path / "b.json", {"source": "b.csv", "ok": True, "converged": False,
                                       "status": "stopped at the iteration limit before converging"})
    out = tmp_path / "merged.json"
    code, _, err = _cli("--", "merge-reports", "--takes", "a.csv", "b.csv", "--reports-dir", str(tmp_path),
                        "--out", str(out))
    assert code == 1
    assert _errors(err) == ["shapespace: error: b.csv: b.csv: the fit stopped before converging"]
    assert json.loads(out.read_text())["status"] == "not_converged"
