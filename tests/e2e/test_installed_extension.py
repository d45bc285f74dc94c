"""End to end: build the zips, install the Linux one into a temporary Blender user folder with
Blender's own extensions API, enable it, run operators and the CLI handler."""
import importlib.util
import json
import os
import re
import subprocess
import sys
import tomllib
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


def test_five_platform_zips_each_with_its_own_wheels(built_zips):
    assert set(built_zips) == {"linux-x64", "windows-x64", "windows-arm64", "macos-arm64", "macos-x64"}
    tags = {"linux-x64": ("manylinux", "_x86_64"), "windows-x64": ("win", "_amd64"),
            "windows-arm64": ("win", "_arm64"), "macos-arm64": ("macosx", "_arm64"),
            "macos-x64": ("macosx", "_x86_64")}
    for plat, path in built_zips.items():
        with zipfile.ZipFile(path) as z:
            names = z.namelist()
            wheels = sorted(n for n in names if n.endswith(".whl") and "python_osc" not in n)
            # one SciPy wheel per Blender Python: 3.11 (Blender 4.2-5.0) and 3.13 (Blender 5.1+)
            assert [w.split("-")[2] for w in wheels] == ["cp311", "cp313"], wheels
            start, end = tags[plat]
            assert all(w.split("/")[-1].startswith("scipy-") and w.split("-")[-1].startswith(start)
                       and w.split("-")[-1].split(".")[0].endswith(end) for w in wheels), wheels
            # and python-osc (Face Cap live capture), pure Python, in every platform's zip
            assert [os.path.basename(n) for n in names if "python_osc" in n] == \
                ["python_osc-1.10.2-py3-none-any.whl"], names
            manifest = z.read("blender_manifest.toml").decode()
            assert f'platforms = ["{plat}"]' in manifest
            assert "__init__.py" in names and "core/blendshape.py" in names and "LICENSE" in names
            info = tomllib.loads(manifest)
            assert info["maintainer"].strip() and "example." not in manifest   # no placeholder maintainer/website
            assert info["version"] == _source_manifest()["version"]
            assert not any(n.startswith(("tests/", "tools/", "assets/", ".ci/")) for n in names)


def _source_manifest() -> dict:
    with open(os.path.join(ROOT, "blender_manifest.toml"), "rb") as fh:
        return tomllib.load(fh)


def _blender_extension(*args):
    """Blender's ``blender --command extension ARGS`` (through the bpy module: tools/run_cli.py)."""
    return subprocess.run([sys.executable, os.path.join(ROOT, "tools", "run_cli.py"), "--command", "extension",
                           *args], capture_output=True, text=True, timeout=300)


def test_every_zip_passes_blenders_validator(built_zips):
    for plat, path in built_zips.items():
        proc = _blender_extension("validate", str(path))
        assert proc.returncode == 0, (plat, proc.stdout[-1000:], proc.stderr[-1000:])


def test_blenders_validator_refuses_a_broken_zip(built_zips, tmp_path):
    """The validator the build runs is a real check: a zip whose manifest has no valid version is refused."""
    bad = tmp_path / "bad.zip"
    _with_version(built_zips["linux-x64"], bad, "not a version")
    proc = _blender_extension("validate", str(bad))
    assert proc.returncode != 0 and "version" in proc.stdout + proc.stderr


def _with_version(src, dst, version: str) -> None:
    """A copy of extension zip ``src`` whose manifest says ``version`` (an earlier build of the same code)."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w", zipfile.ZIP_DEFLATED) as zout:
        for item in zin.infolist():
            data = zin.read(item.filename)
            if item.filename == "blender_manifest.toml":
                data = re.sub(rb'(?m)^version = ".*"$', f'version = "{version}"'.encode(), data, count=1)
            zout.writestr(item, data)


def test_update_channel_install_then_upgrade(built_zips, tmp_path):
    """A studio's update channel: a static repository (tools/build.py publish: Blender's server-generate) added
    as a file:// remote repository; Blender installs the -dev build from it, then upgrades to the release."""
    version = _source_manifest()["version"]
    old = tmp_path / f"shapespace-{version}-dev-linux-x64.zip"
    _with_version(built_zips["linux-x64"], old, version + "-dev")
    assert _blender_extension("validate", str(old)).returncode == 0
    user, home, repo = tmp_path / "blender-user", tmp_path / "home", tmp_path / "repo"
    home.mkdir()
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(user), HOME=str(home))
    script = os.path.join(os.path.dirname(__file__), "update_session.py")
    proc = subprocess.run([sys.executable, script, str(repo), str(old), str(built_zips["linux-x64"])],
                          capture_output=True, text=True, timeout=600, env=env, cwd=str(tmp_path))
    line = [ln for ln in proc.stdout.splitlines() if ln.startswith("E2E-RESULT ")]
    assert proc.returncode == 0 and line, proc.stderr[-3000:]
    seen = json.loads(line[0][len("E2E-RESULT "):])
    assert seen["repo_url"].startswith("file://")
    assert seen["sync"] == ["FINISHED"] and seen["install"] == ["FINISHED"]
    assert seen["installed_enabled"] == ["bl_ext.studio.shapespace"]
    assert seen["installed_module_file"].startswith(str(user))
    assert seen["installed_manifest"] == seen["installed_module_version"] == version + "-dev"
    assert seen["installed_cli_version"] == f"ShapeSpace {version}-dev" and seen["installed_operator"]
    # the higher build is published; the earlier one is kept beside the repository, not deleted
    assert seen["repo_files"] == ["index.html", "index.json", "previous", built_zips["linux-x64"].name]
    assert seen["previous_files"] == [old.name]
    assert seen["resync"] == ["FINISHED"] and seen["upgrade"] == ["FINISHED"]
    assert seen["upgraded_enabled"] == ["bl_ext.studio.shapespace"]
    assert seen["upgraded_manifest"] == seen["upgraded_module_version"] == version
    assert seen["upgraded_module_id"] != seen["installed_module_id"]          # the new code was loaded
    assert seen["upgraded_cli_exit"] == 0 and seen["upgraded_cli_version"] == f"ShapeSpace {version}"
    assert seen["upgraded_operator"]
    assert not (home / ".config" / "blender").exists()


def _build_tool():
    spec = importlib.util.spec_from_file_location("shapespace_build_tool", os.path.join(ROOT, "tools", "build.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_publishing_never_replaces_a_published_zip_with_other_content(built_zips, tmp_path):
    """A build published under a name the repository already holds with other bytes is refused before anything
    is written (clients that saw the old index would get a hash mismatch): publish under a new version."""
    build = _build_tool()
    repo = tmp_path / "repo"
    build.publish([str(built_zips["linux-x64"])], str(repo))
    before = {p.name: p.read_bytes() for p in repo.iterdir() if p.is_file()}
    other = tmp_path / "other" / built_zips["linux-x64"].name
    other.parent.mkdir()
    _with_version(built_zips["linux-x64"], other, _source_manifest()["version"])   # same name, other bytes
    assert other.read_bytes() != before[other.name]
    with pytest.raises(SystemExit, match="publish a new build under a new version"):
        build.publish([str(other)], str(repo))
    assert {p.name: p.read_bytes() for p in repo.iterdir() if p.is_file()} == before
    assert not (repo / "previous").exists()


def test_a_publish_that_fails_leaves_the_repository_as_it_was(built_zips, tmp_path):
    """A zip Blender's server-generate cannot list (its manifest is broken) is refused after the fact: the zips
    and the index are put back, the build that was published stays published."""
    build = _build_tool()
    repo = tmp_path / "repo"
    build.publish([str(built_zips["linux-x64"])], str(repo))
    before = {p.name: p.read_bytes() for p in repo.iterdir() if p.is_file() and p.name != "index.html"}
    broken = tmp_path / "broken" / "shapespace-9.9.9-linux-x64.zip"
    broken.parent.mkdir()
    _with_version(built_zips["linux-x64"], broken, "not a version")
    with pytest.raises(SystemExit, match="the repository is as it was"):
        build.publish([str(broken)], str(repo))
    after = {p.name: p.read_bytes() for p in repo.iterdir() if p.is_file() and p.name != "index.html"}
    assert after == before
    assert not any((repo / "previous").iterdir())


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
    assert seen["child_keys_equal"], "a child process of Blender did not reduce keys as this process does"
    assert seen["child_core_root"].startswith(str(user))      # the child imported the installed core
    assert seen["cli_exit"] == 0
    head = {m["object"]: m for m in seen["cli_json"]["shape_key_meshes"]}["Mesh_2"]
    assert head["shape_keys"] == 52
    assert seen["cli_json"]["shapespace"] == _source_manifest()["version"]    # info names the installed version
    assert seen["after_disable_registered"] is False
    # Blender wrote only into the temporary user folder
    assert not (home / ".config" / "blender").exists()
