"""Run every ShapeSpace test: pytest on bpy 5.0.1 (all tiers), then the Blender tiers on bpy 4.2 LTS.

    python tools/run_tests.py [extra pytest arguments]

Creates the environments on first use (tools/env.py).  Blender always runs
with a temporary user folder (tests/conftest.py), never the real config.
"""
from __future__ import annotations

import os
import subprocess
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import env  # noqa: E402

RUNS = (
    ("bpy50", ["tests"]),
    ("bpy42", ["tests/bridge", "tests/e2e"]),
)


def main(argv) -> int:
    failed = []
    for name, paths in RUNS:
        py = env.ensure(name)
        print(f"\n=== pytest on {name} ===", flush=True)
        code = subprocess.run([py, "-m", "pytest", "-q", *paths, *argv], cwd=env.ROOT).returncode
        if code != 0:
            failed.append(f"{name} (exit {code})")
    if failed:
        print("run_tests: failed on " + ", ".join(failed), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
