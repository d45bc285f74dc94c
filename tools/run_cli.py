"""Run a ShapeSpace command-line command with the ``bpy`` module.

    python tools/run_cli.py FILE -- info [ARGS…]
    python tools/run_cli.py -- info FILE…

Equivalent to ``blender -b FILE --command shapespace info [ARGS…]``: FILE is
opened (.blend) or imported (.glb/.gltf/.fbx/.bvh) first, then the same
handler the extension registers runs.  Exit code and output are the
handler's; a missing or unreadable FILE is a one-line error and exit 1.
"""
from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))


def main(argv) -> int:
    if "--" in argv:
        cut = argv.index("--")
        files, command = argv[:cut], argv[cut + 1:]
    else:
        files, command = [], argv
    if len(files) > 1:
        print("run_cli: error: give at most one FILE before --", file=sys.stderr)
        return 2
    import package  # noqa: E402  (tools/package.py)
    pkg = package.load()
    from shapespace.bridge import assets  # noqa: E402
    from shapespace.core.result import ShapeSpaceError  # noqa: E402
    if files:
        try:
            assets.load(files[0])
        except ShapeSpaceError as exc:
            print(f"shapespace: error: {exc}", file=sys.stderr)
            return 1
    return pkg.cli.main(command)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
