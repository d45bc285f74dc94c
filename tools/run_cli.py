"""Run a ShapeSpace command-line command with the ``bpy`` module.

    python tools/run_cli.py FILE -- info [ARGS…]
    python tools/run_cli.py -- info FILE…

Equivalent to ``blender -b FILE --command shapespace info [ARGS…]``: FILE is
opened (.blend) or imported (.glb/.gltf/.fbx/.bvh) first, then the same
handler the extension registers runs.  Works with any ``python``: without
``bpy`` it re-runs itself in ``.venv/bpy50`` (created on first use).  Exit
code and output are the handler's (stdout: only the JSON); a missing or
unreadable FILE is a one-line error and exit 1.
"""
from __future__ import annotations

import contextlib
import os
import sys

TOOLS = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, TOOLS)


def main(argv) -> int:
    if "--command" in argv:
        return blender_form(argv)
    if "--" in argv:
        cut = argv.index("--")
        files, command = argv[:cut], argv[cut + 1:]
    else:
        files, command = [], argv
    if len(files) > 1:
        print("run_cli: error: give at most one FILE before --", file=sys.stderr)
        return 2
    import env  # noqa: E402  (tools/env.py)
    env.reexec_in("bpy50", os.path.abspath(__file__), argv)
    import package  # noqa: E402  (tools/package.py)
    pkg = package.load()
    from shapespace.bridge import assets  # noqa: E402
    from shapespace.core.result import ShapeSpaceError  # noqa: E402
    with _stored_settings(pkg):
        if files:
            try:
                with assets.redirected_fd(1, 2):          # Blender's log lines: stderr (stdout is the JSON)
                    assets.load(files[0])
            except ShapeSpaceError as exc:
                print(f"shapespace: error: {exc}", file=sys.stderr)
                return 1
        return pkg.cli.main(command, inputs=[os.path.abspath(f) for f in files])


#: Blender options ``blender_form`` accepts (and ignores: the bpy module is always in the background).
BLENDER_FLAGS = ("-b", "--background", "-y", "--enable-autoexec", "--factory-startup")


def blender_form(argv) -> int:
    """``[-b] [-y] [FILE] --command NAME ARGS…``: Blender's own command line, so farm job templates can take this
    script as their ``blender`` executable (``python tools/run_cli.py`` where no Blender binary exists).

    ``--command shapespace``: ShapeSpace's handler — from the extension installed in the user's extensions
    folder (``BLENDER_USER_RESOURCES``) when there is one, as Blender would load it, else from this repository.
    ``--command extension``: Blender's own ``extension`` command (``install-file -r user_default -e ZIP``).
    """
    cut = argv.index("--command")
    name, args = (argv[cut + 1], argv[cut + 2:]) if cut + 1 < len(argv) else ("", [])
    files = [a for a in argv[:cut] if a not in BLENDER_FLAGS]
    if any(a.startswith("-") for a in files) or len(files) > 1 or name not in ("shapespace", "extension"):
        print(f"run_cli: error: expected [-b] [FILE] --command shapespace|extension ARGS…, got {argv}",
              file=sys.stderr)
        return 2
    import env  # noqa: E402  (tools/env.py)
    env.reexec_in("bpy50", os.path.abspath(__file__), argv)
    if name == "extension":
        import bpy  # noqa: E402,F401  (registers Blender's bundled add-ons, bl_pkg among them)
        from bl_pkg.bl_extension_cli import cli_extension_handler  # noqa: E402
        return cli_extension_handler(args)
    pkg = _installed_extension()
    if pkg is None:
        import package  # noqa: E402  (tools/package.py)
        with _stored_settings(package.load()) as pkg:
            return _blender_command(pkg, files, args)
    return _blender_command(pkg, files, args)


def _blender_command(pkg, files, args) -> int:
    import importlib  # noqa: E402
    assets = importlib.import_module(f"{pkg.__name__}.bridge.assets")
    ShapeSpaceError = importlib.import_module(f"{pkg.__name__}.core.result").ShapeSpaceError
    if files:
        try:
            with assets.redirected_fd(1, 2):
                assets.load(files[0])
        except ShapeSpaceError as exc:
            print(f"shapespace: error: {exc}", file=sys.stderr)
            return 1
    return pkg.cli.main(args, inputs=[os.path.abspath(f) for f in files])


@contextlib.contextmanager
def _stored_settings(pkg):
    """``pkg``'s stored settings registered (``Object.shapespace_retarget`` …) for the command, as in Blender where
    the extension is enabled (the commands read what the panels stored on the rig), and unregistered after it:
    Blender 4.2's ``bpy`` module crashes at exit on Python-defined properties still registered."""
    import bpy
    mine = not hasattr(bpy.types.Object, "shapespace_retarget")
    if mine:
        pkg.properties.register()
    try:
        yield pkg
    finally:
        if mine:
            pkg.properties.unregister()


def _installed_extension():
    """The ShapeSpace extension installed in the user's ``user_default`` repository, enabled; or None."""
    import bpy
    folder = os.path.join(bpy.utils.user_resource("EXTENSIONS"), "user_default", "shapespace")
    if not os.path.isfile(os.path.join(folder, "__init__.py")):
        return None
    module = "bl_ext.user_default.shapespace"
    with _stdout_to_stderr():
        bpy.ops.preferences.addon_enable(module=module)
    return sys.modules[module]


class _stdout_to_stderr:
    """Blender's log lines while enabling the extension go to stderr (stdout is the command's JSON)."""

    def __enter__(self):
        sys.stdout.flush()
        self.saved = os.dup(1)
        os.dup2(2, 1)

    def __exit__(self, *exc):
        sys.stdout.flush()
        os.dup2(self.saved, 1)
        os.close(self.saved)
        return False


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
