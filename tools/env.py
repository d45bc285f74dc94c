"""Create (once) the virtual environments the tests, the demo and the build run in.

Each environment ``.venv/<name>`` is described by ``requirements/<name>.txt``, whose header says which
Python it needs (``# python: 3.13``) and, optionally, which packages it must NOT have
(``# without: scipy``):

* ``core``           Python 3.11, numpy/scipy/pytest/ruff/mkdocs, no Blender: the core tier, the linter and
                     the strict documentation build;
* ``bpy50``          Blender 5.0.1 (Python 3.11): the demo, the build and every test tier;
* ``bpy42``/``bpy45`` Blender 4.2 LTS / 4.5 LTS (Python 3.11): the Blender tiers;
* ``bpy52``          Blender 5.2 LTS (Python 3.13): the Blender tiers;
* ``bpy52-noscipy``  Blender 5.2 LTS without SciPy: the installed extension must bring its own.

An environment is rebuilt only when its requirements file changes.  Needs a CPython of each version
asked for (found on PATH, through pyenv, or in ``~/.pyenv/versions``) with ``venv``, and PyPI.

    python tools/env.py [NAME ...]        # create/update them (all when no name is given)
"""
from __future__ import annotations

import glob
import hashlib
import os
import re
import shutil
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ENVS = ("core", "bpy50", "bpy42", "bpy45", "bpy52", "bpy52-noscipy")
DEFAULT_PYTHON = "3.11"


def requirements_path(name: str) -> str:
    return os.path.join(ROOT, "requirements", f"{name}.txt")


def python_of(name: str) -> str:
    return os.path.join(ROOT, ".venv", name, "bin", "python")


def header(name: str) -> dict:
    """The ``# key: value`` lines of a requirements file: ``python`` (version) and ``without`` (list)."""
    info = {"python": DEFAULT_PYTHON, "without": []}
    with open(requirements_path(name), encoding="utf-8") as fh:
        for line in fh:
            m = re.match(r"#\s*(python|without)\s*:\s*(.+?)\s*$", line)
            if m and m[1] == "python":
                info["python"] = m[2]
            elif m:
                info["without"] += [p for p in re.split(r"[,\s]+", m[2]) if p]
    return info


def _reports_version(exe: str, version: str) -> bool:
    try:
        out = subprocess.run([exe, "-c", "import sys, venv; print('%d.%d' % sys.version_info[:2])"],
                             capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired):
        return False
    return out.returncode == 0 and out.stdout.strip() == version


def find_python(version: str) -> str:
    """A CPython ``version`` (``"3.13"``) with ``venv``: this one, on PATH, via pyenv, or under ~/.pyenv."""
    if "%d.%d" % sys.version_info[:2] == version:
        return sys.executable
    candidates = []
    exe = shutil.which(f"python{version}")
    if exe:
        candidates.append(exe)  # may be a pyenv shim that refuses to run: checked below
    pyenv_root = os.environ.get("PYENV_ROOT") or os.path.expanduser("~/.pyenv")
    if shutil.which("pyenv"):
        out = subprocess.run(["pyenv", "prefix", version], capture_output=True, text=True)
        if out.returncode == 0:
            candidates += [os.path.join(p, "bin", f"python{version}") for p in out.stdout.split(os.pathsep)]
    found = glob.glob(os.path.join(pyenv_root, "versions", f"{version}.*", "bin", f"python{version}"))
    candidates += sorted(found, key=lambda p: [int(x) if x.isdigit() else x for x in re.split(r"[.-]", p)],
                         reverse=True)
    for exe in candidates:
        if os.path.isfile(exe) and _reports_version(exe, version):
            return exe
    raise SystemExit(f"env: Python {version} not found (looked on PATH, `pyenv prefix {version}` and "
                     f"{pyenv_root}/versions); install it, e.g. `pyenv install {version}`")


def _pip(py: str, *args: str) -> None:
    subprocess.run([py, "-m", "pip", "--disable-pip-version-check", *args], check=True)


def ensure(name: str) -> str:
    """Path of the environment's python, creating it or installing its requirements if they changed."""
    req = requirements_path(name)
    if not os.path.isfile(req):
        raise SystemExit(f"env: no requirements/{name}.txt")
    info = header(name)
    with open(req, "rb") as fh:
        digest = hashlib.sha256(fh.read()).hexdigest()
    env_dir = os.path.join(ROOT, ".venv", name)
    stamp = os.path.join(env_dir, ".shapespace-requirements")
    py = python_of(name)
    if os.path.isfile(stamp) and os.path.isfile(py):
        with open(stamp) as fh:
            if fh.read().strip() == digest:
                return py
    if os.path.isfile(py) and not _reports_version(py, info["python"]):
        print(f"env: .venv/{name} is not Python {info['python']}; recreating it", file=sys.stderr)
        shutil.rmtree(env_dir)
    if not os.path.isfile(py):
        base = find_python(info["python"])
        print(f"env: creating .venv/{name} with {base}", file=sys.stderr)
        subprocess.run([base, "-m", "venv", env_dir], check=True)
    print(f"env: installing requirements/{name}.txt", file=sys.stderr)
    _pip(py, "install", "--quiet", "-r", req)
    for pkg in info["without"]:
        probe = subprocess.run([py, "-c", f"import importlib.util as u; print(u.find_spec({pkg!r}) is not None)"],
                               capture_output=True, text=True, check=True)
        if probe.stdout.strip() == "True":
            print(f"env: removing {pkg} from .venv/{name} (it must not be there)", file=sys.stderr)
            _pip(py, "uninstall", "--quiet", "--yes", pkg)
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
