"""Loading files through Blender's own readers (.blend, glTF, FBX, BVH).

A file an importer cannot read is one :class:`~core.result.ShapeSpaceError` line: the importer's own
traceback and log, which Blender prints on stdout and stderr, are captured and only the error they end with
is kept (a successful import's log is passed on to stderr, never stdout).
"""
from __future__ import annotations

import contextlib
import os
import re
import sys
import tempfile

import bpy

from ..core.errors import ErrorCode
from ..core.result import ShapeSpaceError

IMPORTERS = {
    ".glb": ("import_scene", "gltf"),
    ".gltf": ("import_scene", "gltf"),
    ".fbx": ("import_scene", "fbx"),
    ".bvh": ("import_anim", "bvh"),
}

#: The last line of a Python traceback: ``SomeError: message``.
_ERROR_LINE = re.compile(r"^(?:[\w.]+\.)?(\w*(?:Error|Exception)): (.+)$")


def load(path: str, replace: bool = True) -> list:
    """Open a .blend or import a glTF/FBX/BVH file; return the names of the new objects.

    Parameters
    ----------
    path : str
    replace : bool
        For imports: start from an empty scene first (``read_factory_settings``).

    Raises
    ------
    core.ShapeSpaceError
        Missing file, not a regular file, unsupported extension, or a file Blender cannot read (one line;
        the importer's traceback is not printed).
    """
    if not os.path.lexists(path):
        raise ShapeSpaceError(f"file not found: {path}", ErrorCode.MISSING_FILE)
    if not os.path.isfile(path):
        raise ShapeSpaceError(f"{path}: is a directory or device, not a file", ErrorCode.NOT_A_FILE)
    ext = os.path.splitext(path)[1].lower()
    if ext == ".blend":
        try:
            bpy.ops.wm.open_mainfile(filepath=path, load_ui=False)
        except RuntimeError as exc:
            raise ShapeSpaceError(f"cannot read {path}: {_first_line(exc)}", ErrorCode.CORRUPT_FILE) from None
        return [ob.name for ob in bpy.data.objects]
    if ext not in IMPORTERS:
        raise ShapeSpaceError(
            f"unsupported file type {ext or '(none)'} for {path}; use .blend, .glb, .gltf, .fbx or .bvh",
            ErrorCode.UNSUPPORTED_FILE)
    if replace:
        bpy.ops.wm.read_factory_settings(use_empty=True)
    before = set(bpy.data.objects.keys())
    group, name = IMPORTERS[ext]
    op = getattr(getattr(bpy.ops, group), name)
    log = []
    try:
        with captured_output(log):
            result = op(filepath=path)
    except Exception as exc:  # an importer may raise anything on a damaged file
        raise ShapeSpaceError(f"cannot read {path}: {_importer_error(exc, log)}", ErrorCode.CORRUPT_FILE) from None
    if "FINISHED" not in result:
        raise ShapeSpaceError(f"cannot read {path}: {_importer_error(None, log)}", ErrorCode.CORRUPT_FILE)
    _replay(log)
    return [n for n in bpy.data.objects.keys() if n not in before]


def _flush_c_stdio() -> None:
    """Flush C ``stdio`` buffers (Blender's own log lines) so an fd switch does not reorder them."""
    try:
        import ctypes
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError, TypeError):
        pass


@contextlib.contextmanager
def redirected_fd(fd: int, target: int):
    """Send everything written to file descriptor ``fd`` (Python and C alike) to ``target`` for the block;
    yields a duplicate of the original ``fd`` (or ``None`` when ``fd`` cannot be redirected)."""
    streams = {1: sys.stdout, 2: sys.stderr}
    try:
        saved = os.dup(fd)
    except OSError:
        yield None
        return
    for stream in streams.values():
        with contextlib.suppress(Exception):
            stream.flush()
    _flush_c_stdio()
    os.dup2(target, fd)
    try:
        yield saved
    finally:
        for stream in streams.values():
            with contextlib.suppress(Exception):
                stream.flush()
        _flush_c_stdio()
        os.dup2(saved, fd)
        os.close(saved)


@contextlib.contextmanager
def captured_output(log: list):
    """Collect what is written on stdout and stderr during the block (appended to ``log`` as one string)."""
    with tempfile.TemporaryFile() as tmp:
        try:
            with redirected_fd(1, tmp.fileno()), redirected_fd(2, tmp.fileno()):
                yield
        finally:
            tmp.seek(0)
            log.append(tmp.read().decode("utf-8", errors="replace"))


def _replay(log: list) -> None:
    """Pass a successful importer's log on to stderr."""
    text = "".join(log)
    if text.strip():
        sys.stderr.write(text if text.endswith("\n") else text + "\n")


def _importer_error(exc, log: list) -> str:
    """The one line that says why an importer failed: the error its traceback ends with."""
    lines = [ln.strip() for ln in (str(exc) if exc is not None else "").splitlines() + "".join(log).splitlines()]
    found = [m for m in (_ERROR_LINE.match(ln.replace("Error: ", "", 1) if ln.startswith("Error: ") else ln)
                         for ln in lines) if m]
    if found:
        kind, message = found[-1].groups()
        return f"{message} ({kind})" if kind not in ("RuntimeError", "Exception") else message
    return _first_line(exc) if exc is not None else "the importer gave up"


def _first_line(exc) -> str:
    text = [t.strip() for t in str(exc).strip().splitlines()]
    text = [t for t in text if t and not t.startswith("Location:")]
    return (text[-1] if text else type(exc).__name__).replace("Error: ", "").strip()
