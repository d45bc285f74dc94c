"""Run every ShapeSpace check: ruff, then pytest on each supported Blender.

    python tools/run_tests.py [--env NAME ...] [extra pytest arguments]

1. ``ruff check .`` (settings in pyproject.toml) in ``.venv/core``; lint errors fail the run.
2. ``mkdocs build --strict`` (mkdocs.yml) in ``.venv/core`` into ``site/``: a broken link or anchor, a missing
   page or a page left out of the navigation fails the run.
3. pytest, one run per line of ``RUNS``: the core tier on a plain Python without Blender (the Python,
   NumPy and SciPy of Blender 5.0's environment, so it is not run again there), the Blender tiers on 5.0,
   4.2 LTS, 4.5 LTS and 5.2 LTS (Python 3.13), and the installed-extension test once more on 5.2 LTS in a
   venv WITHOUT SciPy, so the SciPy wheel the extension bundles is what runs.  Tests marked ``one_blender``
   (ShapeSpace's own command-line and report logic) run on 5.0 only; on 4.2 the tests marked ``rigify``
   run last (tests/bridge/conftest.py says why).  Every run passes ``--run-slow`` (tests/conftest.py): the
   perf/scale tests marked ``slow``, which a plain ``pytest tests/core`` skips for a fast inner loop, run here
   too.

``--env NAME`` (repeatable) runs only those environments' lines.  Creates the environments on first
use (tools/env.py).  Blender always runs with a temporary user folder (tests/conftest.py), never the
real configuration.  Ends with one line of totals over all runs and the time each took.
"""
from __future__ import annotations

import os
import re
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import env  # noqa: E402

BLENDER_TIERS = ["tests/bridge", "tests/e2e"]
RUNS = (  # (environment, pytest paths, extra environment variables)
    ("core", ["tests/core"], {}),
    ("bpy50", BLENDER_TIERS, {}),
    ("bpy42", BLENDER_TIERS, {}),
    ("bpy45", BLENDER_TIERS, {}),
    ("bpy52", BLENDER_TIERS, {}),
    ("bpy52-noscipy", ["tests/e2e/test_installed_extension.py"], {"SHAPESPACE_E2E_BUNDLED_SCIPY": "1"}),
)
LINT_ENV = "core"
DOCS_ENV = "core"
COUNT = re.compile(r"(\d+) (passed|failed|errors?|skipped|xfailed|xpassed|deselected)\b")


def lint() -> int:
    """Number of ruff findings (0 when clean)."""
    py = env.ensure(LINT_ENV)
    print("\n=== ruff check . ===", flush=True)
    proc = subprocess.run([py, "-m", "ruff", "check", "--output-format", "concise", "."], cwd=env.ROOT,
                          capture_output=True, text=True)
    sys.stdout.write(proc.stdout + proc.stderr)
    if proc.returncode == 0:
        return 0
    m = re.search(r"Found (\d+) error", proc.stdout)
    return int(m[1]) if m else 1


def docs() -> bool:
    """Build the documentation site strictly (mkdocs.yml); True when it built without a warning."""
    py = env.ensure(DOCS_ENV)
    print("\n=== mkdocs build --strict ===", flush=True)
    proc = subprocess.run([py, "-m", "mkdocs", "build", "--strict"], cwd=env.ROOT,
                          capture_output=True, text=True)
    sys.stdout.write(proc.stdout + proc.stderr)
    return proc.returncode == 0


def pytest_run(name: str, paths, extra_env: dict, argv) -> tuple[int, dict]:
    """Run pytest in one environment, echoing its output; its exit code and closing-line counts."""
    py = env.ensure(name)
    print(f"\n=== pytest on {name}: {' '.join(paths)} ===", flush=True)
    proc = subprocess.Popen([py, "-m", "pytest", "-q", "--run-slow", *paths, *argv], cwd=env.ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env=dict(os.environ, **extra_env))
    last = ""
    for line in proc.stdout:
        sys.stdout.write(line)
        sys.stdout.flush()
        if COUNT.search(line):
            last = line
    code = proc.wait()
    counts = {}
    for n, word in COUNT.findall(last):
        key = "error" if word.startswith("error") else word
        counts[key] = counts.get(key, 0) + int(n)
    return code, counts


def parse_args(argv):
    only, rest = [], list(argv)
    while rest[:1] == ["--env"] and len(rest) > 1:
        only.append(rest[1])
        rest = rest[2:]
    unknown = set(only) - {name for name, _, _ in RUNS}
    if unknown:
        raise SystemExit(f"run_tests: no run for {sorted(unknown)}; runs are {[n for n, _, _ in RUNS]}")
    return only, rest


def main(argv) -> int:
    only, pytest_args = parse_args(argv)
    failed, timings, totals = [], [], {}
    t0 = time.monotonic()
    lint_errors = lint()
    timings.append(("ruff", time.monotonic() - t0))
    if lint_errors:
        failed.append(f"ruff ({lint_errors} errors)")
    t0 = time.monotonic()
    if not docs():
        failed.append("docs (mkdocs build --strict)")
    timings.append(("docs", time.monotonic() - t0))
    for name, paths, extra_env in RUNS:
        if only and name not in only:
            continue
        t0 = time.monotonic()
        code, counts = pytest_run(name, paths, extra_env, pytest_args)
        timings.append((name, time.monotonic() - t0))
        for key, n in counts.items():
            totals[key] = totals.get(key, 0) + n
        if code == 5 and pytest_args:
            continue  # the extra arguments selected nothing in this run
        if code != 0:
            failed.append(f"{name} (exit {code})")
    print("\n=== times ===")
    for name, seconds in timings:
        print(f"  {name:<14} {seconds:7.1f} s")
    print(f"  {'total':<14} {sum(s for _, s in timings):7.1f} s")
    if failed:
        print("run_tests: failed on " + ", ".join(failed), file=sys.stderr)
    n_failed = totals.get("failed", 0) + totals.get("error", 0)
    print(f"total: {totals.get('passed', 0)} passed, {n_failed} failed, {totals.get('skipped', 0)} skipped",
          flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
