"""End to end: build the zips, install the Linux one into a temporary Blender user folder with
Blender's own extensions API, enable it, run operators and the CLI handler."""
import json
import os
import subprocess
import sys
import zipfile

import pytest

from support import ASSETS, ROOT

pytest.importorskip("bpy")

# Set by tools/run_tests.py for the run on a venv without SciPy: there the extension must work on
# the SciPy wheel it bundles, and this asserts that the venv really has no SciPy of its own.
BUNDLED_SCIPY_ONLY = os.environ.get("SHAPESPACE_E2E_BUNDLED_SCIPY") == "1"


@pytest.fixture(scope="session")
def built_zips(tmp_path_factory):
    out = tmp_path_factory.mktemp("dist")
    proc = subprocess.run([sys.executable, os.path.join(ROOT, "tools", "build.py"), "--out", str(out)],
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return {p.name.split("-", 2)[-1][:-4]: p for p in out.glob("*.zip")}


def test_four_platform_zips_each_with_its_own_wheels(built_zips):
    assert set(built_zips) == {"linux-x64", "windows-x64", "macos-arm64", "macos-x64"}
    tags = {"linux-x64": "manylinux", "windows-x64": "win_amd64", "macos-arm64": "arm64",
            "macos-x64": "macosx_10_13_x86_64"}
    for plat, path in built_zips.items():
        with zipfile.ZipFile(path) as z:
            names = z.namelist()
            wheels = sorted(n for n in names if n.endswith(".whl") and "python_osc" not in n)
            # one SciPy wheel per Blender Python: 3.11 (Blender 4.2-5.0) and 3.13 (Blender 5.1+)
            assert [w.split("-")[2] for w in wheels] == ["cp311", "cp313"], wheels
            assert all(tags[plat] in w and "scipy" in w for w in wheels), wheels
            # and python-osc (Face Cap live capture), pure Python, in every platform's zip
            assert [os.path.basename(n) for n in names if "python_osc" in n] == \
                ["python_osc-1.10.2-py3-none-any.whl"], names
            manifest = z.read("blender_manifest.toml").decode()
            assert f'platforms = ["{plat}"]' in manifest
            assert "__init__.py" in names and "core/blendshape.py" in names and "LICENSE" in names
            assert 'website = "' in manifest and "maintainer = " in manifest and "@" in manifest
            assert not any(n.startswith(("tests/", "tools/", "assets/", ".ci/")) for n in names)


def test_install_enable_run_operator_and_cli(built_zips, tmp_path):
    user = tmp_path / "blender-user"
    home = tmp_path / "home"
    home.mkdir()
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(user), HOME=str(home))
    script = os.path.join(os.path.dirname(__file__), "installed_session.py")
    asset = os.path.join(ASSETS, "facecap", "facecap_decoded.glb")
    proc = subprocess.run([sys.executable, script, str(built_zips["linux-x64"]), asset],
                          capture_output=True, text=True, timeout=600, env=env, cwd=str(tmp_path))
    line = [ln for ln in proc.stdout.splitlines() if ln.startswith("E2E-RESULT ")]
    assert proc.returncode == 0 and line, proc.stderr[-3000:]
    seen = json.loads(line[0][len("E2E-RESULT "):])
    assert seen["install"] == ["FINISHED"]
    assert seen["addons"] == ["bl_ext.user_default.shapespace"]
    assert seen["module_file"].startswith(str(user))          # the installed copy, not the repo
    assert seen["cli_registered"]
    assert "scipy" in seen["wheel_dirs"] and seen["site_on_path"]
    assert seen["scipy_abis"] == [seen["python"].replace(".", "")], seen["scipy_abis"]  # the wheel for this Python
    assert seen["scipy_file"], "the operators ran without importing scipy"
    if BUNDLED_SCIPY_ONLY:
        assert not seen["venv_has_scipy"], "this run needs a Python without its own SciPy"
    if not seen["venv_has_scipy"]:  # so the SciPy that ran is the bundled wheel for this Python
        assert seen["scipy_file"].startswith(seen["site"] + os.sep), (seen["scipy_file"], seen["site"])
    assert seen["check_rig"] == ["FINISHED"] and seen["key_sliders"] == ["FINISHED"]
    assert seen["add_pin"] == ["FINISHED"] and seen["solve_pins"] == ["FINISHED"]
    assert seen["retarget"] == ["FINISHED"] and seen["analyse_rig"] == ["FINISHED"]
    assert seen["learn_face_prior"] == ["FINISHED"] and seen["prior_stored"]
    assert seen["cli_exit"] == 0
    head = {m["object"]: m for m in seen["cli_json"]["shape_key_meshes"]}["Mesh_2"]
    assert head["shape_keys"] == 52
    assert seen["after_disable_registered"] is False
    # Blender wrote only into the temporary user folder
    assert not (home / ".config" / "blender").exists()
