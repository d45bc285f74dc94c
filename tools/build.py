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
3. Names them ``dist/shapespace-<version>-<platform>.zip`` and checks each holds exactly the
   manifest's wheels for its platform plus every pure-Python wheel.
"""
from __future__ import annotations

import argparse
import glob
import importlib.util
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
WHEEL_NAME = re.compile(r"(?P<dist>[^-]+)-(?P<ver>[^-]+)-(?P<py>cp\d+|py\d+)-(?P<abi>[^-]+)-(?P<plat>.+)\.whl$")
BLENDER_PLATFORM = {  # Blender platform → (start, end) of its wheels' platform tags
    "linux-x64": ("manylinux", "_x86_64"),
    "windows-x64": ("win", "_amd64"),
    "macos-arm64": ("macosx", "_arm64"),
    "macos-x64": ("macosx", "_x86_64"),
}
PLATFORM_TAG = {  # wheel platform tag → pip --platform
    "manylinux_2_17_x86_64.manylinux2014_x86_64": "manylinux_2_17_x86_64",
    "win_amd64": "win_amd64",
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
        check_wheels(path, info.get("wheels", []))
    return made


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
    args = ap.parse_args(argv)
    for path in build(args.out):
        print(path, f"{os.path.getsize(path) / 1e6:.1f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
