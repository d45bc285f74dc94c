"""``shapespace --version`` and ``info``'s ``shapespace`` field both say the version in blender_manifest.toml
(the one place it is written), through tools/run_cli.py (the handler Blender's --command runs)."""
import json
import os
import subprocess
import sys
import tomllib

from support import ASSETS, ROOT

RUN_CLI = os.path.join(ROOT, "tools", "run_cli.py")


def _manifest_version() -> str:
    with open(os.path.join(ROOT, "blender_manifest.toml"), "rb") as fh:
        return tomllib.load(fh)["version"]


def _run(*args):
    return subprocess.run([sys.executable, RUN_CLI, *args], capture_output=True, text=True, timeout=300)


def test_version_flag_prints_the_manifest_version_and_exits_0():
    proc = _run("--", "--version")
    assert proc.returncode == 0, proc.stderr
    # the last line: Blender may log a line first (bpy 5.2: "color_management | Using OCIO=…")
    assert proc.stdout.strip().splitlines()[-1] == f"ShapeSpace {_manifest_version()}"


def test_info_reports_the_manifest_version():
    proc = _run(os.path.join(ASSETS, "facecap", "facecap_decoded.glb"), "--", "info")
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(proc.stdout[proc.stdout.index("{"):])
    assert rep["shapespace"] == _manifest_version() and rep["blender"]
