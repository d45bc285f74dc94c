"""Create (once) the virtual environments that hold Blender as a Python module.

``.venv/bpy50`` (bpy 5.0.1) runs the demo and every test tier;
``.venv/bpy42`` (bpy 4.2 LTS) runs the Blender tiers again on the oldest
supported Blender.  Each is rebuilt only when its requirements file changes.
Needs nothing but a CPython 3.11 with ``venv`` and access to PyPI.
"""
from __future__ import annotations

import hashlib
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ENVS = ("bpy50", "bpy42")


def python_of(name: str) -> str:
    return os.path.join(ROOT, ".venv", name, "bin", "python")


def ensure(name: str) -> str:
    """Path of the environment's python, installing its requirements if they changed."""
    if sys.version_info[:2] != (3, 11):
        raise SystemExit(f"ShapeSpace needs Python 3.11 (Blender's); this is {sys.version.split()[0]}")
    req = os.path.join(ROOT, "requirements", f"{name}.txt")
    with open(req, "rb") as fh:
        digest = hashlib.sha256(fh.read()).hexdigest()
    env_dir = os.path.join(ROOT, ".venv", name)
    stamp = os.path.join(env_dir, ".shapespace-requirements")
    py = python_of(name)
    if os.path.isfile(stamp) and os.path.isfile(py):
        with open(stamp) as fh:
            if fh.read().strip() == digest:
                return py
    if not os.path.isfile(py):
        print(f"env: creating .venv/{name}", file=sys.stderr)
        subprocess.run([sys.executable, "-m", "venv", env_dir], check=True)
    print(f"env: installing requirements/{name}.txt", file=sys.stderr)
    subprocess.run([py, "-m", "pip", "install", "--quiet", "--disable-pip-version-check", "-r", req],
                   check=True)
    with open(stamp, "w") as fh:
        fh.write(digest + "\n")
    return py


def reexec_in(name: str, script: str, argv) -> None:
    """Re-run ``script`` with the environment's python unless this python already has ``bpy``."""
    import importlib.util
    if importlib.util.find_spec("bpy") is not None:
        return
    py = ensure(name)
    os.execv(py, [py, script, *argv])


if __name__ == "__main__":
    for env in sys.argv[1:] or ENVS:
        print(ensure(env))
