"""Build the extension zips, one per platform, with Blender's own builder.

    python tools/build.py [--out dist]

Runs itself in ``.venv/bpy50`` (tools/env.py) unless this Python already has ``bpy``.

1. Downloads the wheels listed in ``blender_manifest.toml`` into ``./wheels`` unless present: SciPy for
   each wheel's CPython version and platform, pure-Python wheels (``py3-none-any``: python-osc) once.
2. Runs Blender's extension builder (``blender_ext.py build
   --split-platforms``, shipped with Blender and the ``bpy`` module), which
   validates the manifest and writes one zip per platform holding only that
   platform's wheels (one per Python version: Blender installs the one matching its Python) and the
   pure-Python ones.
3. Names them ``dist/shapespace-<version>-<platform>.zip``, runs Blender's validator on each finished zip
   (``blender --command extension validate ZIP``, through the bpy module: ``tools/run_cli.py``) and checks each
   holds exactly the manifest's wheels for its platform plus every pure-Python wheel.
4. With ``--repo DIR``: publishes the zips into DIR, a static extension repository a studio can host
   (a web server or a shared folder: Blender's *Add Remote Repository* with ``https://…/index.json`` or
   ``file:///…/index.json``).  This version's zips are copied in, older ShapeSpace zips are moved to
   ``DIR/previous/`` (one version per platform in the listing; nothing is deleted), and Blender's
   ``extension server-generate --html`` writes ``index.json`` and ``index.html``.  A zip of the same name but
   other content is refused before anything is written: publish a new build under a new version.
"""
from __future__ import annotations

import argparse
import filecmp
import glob
import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
import tomllib
import zipfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import env  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RUN_CLI = os.path.join(ROOT, "tools", "run_cli.py")
WHEEL_NAME = re.compile(r"(?P<dist>[^-]+)-(?P<ver>[^-]+)-(?P<py>cp\d+|py\d+)-(?P<abi>[^-]+)-(?P<plat>.+)\.whl$")
BLENDER_PLATFORM = {  # Blender platform → (start, end) of its wheels' platform tags
    "linux-x64": ("manylinux", "_x86_64"),
    "windows-x64": ("win", "_amd64"),
    "windows-arm64": ("win", "_arm64"),
    "macos-arm64": ("macosx", "_arm64"),
    "macos-x64": ("macosx", "_x86_64"),
}
PLATFORM_TAG = {  # wheel platform tag → pip --platform
    "manylinux_2_17_x86_64.manylinux2014_x86_64": "manylinux_2_17_x86_64",
    "manylinux_2_27_x86_64.manylinux_2_28_x86_64": "manylinux_2_28_x86_64",
    "win_amd64": "win_amd64",
    "win_arm64": "win_arm64",
    "macosx_12_0_arm64": "macosx_12_0_arm64",
    "macosx_10_13_x86_64": "macosx_10_13_x86_64",
}


def manifest() -> dict:
    with open(os.path.join(ROOT, "blender_manifest.toml"), "rb") as fh:
        return tomllib.load(fh)


def fetch_wheels(wheels) -> None:
    os.makedirs(os.path.join(ROOT, "wheels"), exist_ok=True)
    for rel in wheels:
        path = os.path.normpath(os.path.join(ROOT, rel))
        if os.path.isfile(path):
            continue
        name = os.path.basename(path)
        cmd = pip_download_command(name, os.path.dirname(path))
        print("build: fetching", name, file=sys.stderr)
        subprocess.run(cmd, check=True)
        if not os.path.isfile(path):
            raise SystemExit(f"build: pip did not produce {name}")


def pip_download_command(name: str, dest: str) -> list:
    """The ``pip download`` command that fetches wheel file *name* (for its own Python and platform) into *dest*."""
    m = WHEEL_NAME.match(name)
    if not m:
        raise SystemExit(f"build: cannot parse wheel name {name}")
    cmd = [sys.executable, "-m", "pip", "download", "--quiet", "--no-deps", "--only-binary=:all:", "-d", dest]
    if not pure_python(name):
        plat = PLATFORM_TAG.get(m["plat"], m["plat"].split(".")[0])
        cmd += ["--python-version", m["py"][2:3] + "." + m["py"][3:], "--implementation", "cp",
                "--platform", plat]
    cmd.append(f"{m['dist']}=={m['ver']}")
    return cmd


def pure_python(wheel: str) -> bool:
    """A wheel for every platform and Python 3 (``py3-none-any``): it goes into every platform's zip."""
    m = WHEEL_NAME.match(os.path.basename(wheel))
    return m is not None and m["py"].startswith("py") and m["abi"] == "none" and m["plat"] == "any"


def blender_ext_script() -> str:
    spec = importlib.util.find_spec("bpy")
    if spec is None or spec.origin is None:
        raise SystemExit("build: the bpy module is needed (pip install bpy) for Blender's extension builder")
    hits = glob.glob(os.path.join(os.path.dirname(spec.origin), "*", "scripts", "addons_core", "bl_pkg",
                                  "cli", "blender_ext.py"))
    if not hits:
        raise SystemExit("build: blender_ext.py not found in the bpy module")
    return hits[0]


def build(out_dir: str) -> list:
    info = manifest()
    fetch_wheels(info.get("wheels", []))
    tmp = os.path.join(ROOT, "build", "ext")
    shutil.rmtree(tmp, ignore_errors=True)
    os.makedirs(tmp)
    cmd = [sys.executable, blender_ext_script(), "build", "--source-dir", ROOT, "--output-dir", tmp,
           "--split-platforms"]
    if subprocess.run(cmd).returncode != 0:
        raise SystemExit("build: Blender's extension builder rejected the package (see above)")
    os.makedirs(out_dir, exist_ok=True)
    made = []
    for zpath in sorted(glob.glob(os.path.join(tmp, "*.zip"))):
        plat = os.path.basename(zpath)[:-4].rsplit("-", 1)[-1].replace("_", "-")
        dest = os.path.join(out_dir, f"{info['id']}-{info['version']}-{plat}.zip")
        shutil.move(zpath, dest)
        made.append(dest)
    expected = {p for p in info["platforms"]}
    got = {os.path.basename(p)[:-4].split("-", 2)[-1] for p in made}
    if got != expected:
        raise SystemExit(f"build: expected zips for {sorted(expected)}, got {sorted(got)}")
    for path in made:
        validate(path)
        check_wheels(path, info.get("wheels", []))
    return made


def blender_extension(args) -> subprocess.CompletedProcess:
    """Blender's own ``blender --command extension ARGS…`` (validate, server-generate, …), run with the bpy
    module (there is no ``blender`` binary in the bpy wheel): ``tools/run_cli.py --command extension``."""
    return subprocess.run([sys.executable, RUN_CLI, "--command", "extension", *args], capture_output=True,
                          text=True)


def validate(zip_path: str) -> None:
    """Blender's validator (``blender --command extension validate``) must accept the finished zip."""
    proc = blender_extension(["validate", zip_path])
    if proc.returncode != 0:
        why = (proc.stdout + proc.stderr).strip().splitlines() or ["no output"]
        raise SystemExit(f"build: Blender's validator rejected {os.path.basename(zip_path)}: {why[-1]}")
    print("build: validated", os.path.basename(zip_path), file=sys.stderr)


def publish(zips, repo_dir: str) -> str:
    """Publish ``zips`` (one version's, all of one extension) into the static repository ``repo_dir``; returns
    the path of its ``index.json``.

    Older zips of the same extension move to ``repo_dir/previous/``; other extensions' zips stay.  Every
    check runs before anything is copied or moved.
    """
    ids = {_zip_manifest(z).get("id") for z in zips}
    if len(ids) != 1 or None in ids:
        raise SystemExit(f"build: publish one extension at a time, got {sorted(ids)}")
    names = {os.path.basename(z) for z in zips}
    os.makedirs(repo_dir, exist_ok=True)
    previous = os.path.join(repo_dir, "previous")
    older = []
    for path in sorted(glob.glob(os.path.join(repo_dir, "*.zip"))):
        name = os.path.basename(path)
        if name in names:
            if not filecmp.cmp(path, next(z for z in zips if os.path.basename(z) == name), shallow=False):
                raise SystemExit(f"build: {repo_dir} already holds another {name}: publish a new build under a "
                                 "new version (blender_manifest.toml)")
        elif _zip_manifest(path).get("id") in ids:
            if os.path.exists(os.path.join(previous, name)):
                raise SystemExit(f"build: {os.path.join(previous, name)} exists: move it away first")
            older.append(path)
    if older:
        os.makedirs(previous, exist_ok=True)
    moved = [(path, os.path.join(previous, os.path.basename(path))) for path in older]
    copied = [os.path.join(repo_dir, os.path.basename(z)) for z in zips
              if not os.path.exists(os.path.join(repo_dir, os.path.basename(z)))]
    for src, dest in moved:
        shutil.move(src, dest)
    for dest in copied:
        shutil.copyfile(next(z for z in zips if os.path.basename(z) == os.path.basename(dest)), dest)
    index = os.path.join(repo_dir, "index.json")
    why = _server_generate(repo_dir, index, ids, names)
    if why:                    # put the repository back as it was (the old index still lists the old zips)
        for dest in copied:
            os.remove(dest)
        for src, dest in moved:
            shutil.move(dest, src)
        _server_generate(repo_dir, index, ids, None)
        raise SystemExit(f"build: {why}; the repository is as it was")
    return index


def _server_generate(repo_dir: str, index: str, ids: set, names) -> str:
    """Run Blender's ``extension server-generate --html`` in ``repo_dir``; '' when ``index`` then lists exactly
    ``names`` for the extension ``ids`` (any listing when ``names`` is None), else why not."""
    proc = blender_extension(["server-generate", "--repo-dir", repo_dir, "--html"])
    if proc.returncode != 0 or not os.path.isfile(index):
        lines = (proc.stdout + proc.stderr).strip().splitlines() or ["no output"]
        return f"Blender's server-generate failed in {repo_dir}: {lines[-1]}"
    with open(index, encoding="utf-8") as fh:
        listed = {os.path.basename(e["archive_url"]) for e in json.load(fh)["data"] if e["id"] in ids}
    if names is not None and listed != names:
        return f"{index} lists {sorted(listed)}, expected {sorted(names)}"
    return ""


def _zip_manifest(path: str) -> dict:
    """The ``blender_manifest.toml`` at the root of an extension zip ({} when there is none)."""
    try:
        with zipfile.ZipFile(path) as z:
            return tomllib.loads(z.read("blender_manifest.toml").decode("utf-8"))
    except (KeyError, zipfile.BadZipFile, tomllib.TOMLDecodeError, UnicodeDecodeError):
        return {}


def check_wheels(zip_path: str, wheels) -> None:
    """The zip for one platform must hold exactly the manifest's wheels for that platform and every pure-Python
    wheel (``py3-none-any``)."""
    plat = os.path.basename(zip_path)[:-4].split("-", 2)[-1]
    if plat not in BLENDER_PLATFORM:
        raise SystemExit(f"build: no wheel platform tag known for {plat}")
    start, end = BLENDER_PLATFORM[plat]
    want = sorted(name for name in map(os.path.basename, wheels) if pure_python(name)
                  or any(t.startswith(start) and t.endswith(end) for t in WHEEL_NAME.match(name)["plat"].split(".")))
    with zipfile.ZipFile(zip_path) as z:
        got = sorted(os.path.basename(n) for n in z.namelist() if n.endswith(".whl"))
    if got != want:
        raise SystemExit(f"build: {os.path.basename(zip_path)} holds wheels {got}, expected {want}")


def main(argv=None) -> int:
    env.reexec_in("bpy50", os.path.abspath(__file__), sys.argv[1:] if argv is None else argv)
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=os.path.join(ROOT, "dist"))
    ap.add_argument("--repo", help="also publish the zips into this static extension repository (index.json)")
    args = ap.parse_args(argv)
    made = build(args.out)
    for path in made:
        print(path, f"{os.path.getsize(path) / 1e6:.1f} MB")
    if args.repo:
        print(publish(made, args.repo))
    return 0


if __name__ == "__main__":
    sys.exit(main())
