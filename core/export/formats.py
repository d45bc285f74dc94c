"""The export formats, what each can carry, and checks on the output path (before any work is done)."""
from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass

from ..errors import ErrorCode
from ..result import ShapeSpaceError

__all__ = ["FORMATS", "ExportFormat", "check_format", "check_output_path", "format_of"]


@dataclass(frozen=True)
class ExportFormat:
    """One export format.

    Attributes
    ----------
    name : str
        ``gltf``, ``fbx`` or ``abc`` (the command line's ``--format``).
    extensions : tuple of str
        Allowed output extensions, the default first.
    morph_targets : bool
        Carries shape keys as morph targets with animated weights (else: a point cache of the evaluated
        mesh per frame, so shape keys, drivers, skinning and every deformer arrive exact but not editable).
    per_vertex_correctives : str
        How weighted PSD (per vertex, not a weighted sum of keys) gets through: ``"exact"`` (the point
        cache) or ``"per_frame"`` (one morph target per baked frame, weight 1 at its frame, linear between).
    """

    name: str
    extensions: tuple
    morph_targets: bool
    per_vertex_correctives: str


FORMATS = {
    "gltf": ExportFormat("gltf", (".glb", ".gltf"), True, "per_frame"),
    "fbx": ExportFormat("fbx", (".fbx",), True, "per_frame"),
    "abc": ExportFormat("abc", (".abc",), False, "exact"),
}


def check_format(name: str) -> ExportFormat:
    """The format called ``name`` (code ``format`` naming the choices otherwise)."""
    fmt = FORMATS.get(str(name).lower())
    if fmt is None:
        raise ShapeSpaceError(f"unknown export format {name!r}: use {', '.join(FORMATS)}", ErrorCode.FORMAT)
    return fmt


def format_of(path: str) -> ExportFormat:
    """The format an output path's extension names (code ``format`` when none does)."""
    ext = os.path.splitext(path)[1].lower()
    for fmt in FORMATS.values():
        if ext in fmt.extensions:
            return fmt
    known = ", ".join(e for f in FORMATS.values() for e in f.extensions)
    raise ShapeSpaceError(f"cannot tell the export format of {path!r}: give it one of the extensions {known}",
                          ErrorCode.FORMAT)


def check_output_path(path: str, fmt: ExportFormat, inputs: tuple = ()) -> str:
    """The absolute output path, checked before anything is baked.

    Refused (one line naming the path): an empty path; an extension that does not match ``fmt``
    (code ``format``); a folder that does not exist or cannot be written (``unwritable``); a directory
    (``not_a_file``); an existing file that cannot be replaced (``unwritable``); one of ``inputs`` (the
    open .blend, a source file: ``overwrite``).
    """
    if not path:
        raise ShapeSpaceError("no output file given", ErrorCode.USAGE)
    path = os.path.abspath(os.path.expanduser(path))
    ext = os.path.splitext(path)[1].lower()
    if ext not in fmt.extensions:
        raise ShapeSpaceError(f"{path}: a {fmt.name} file must end in {' or '.join(fmt.extensions)}",
                              ErrorCode.FORMAT)
    folder = os.path.dirname(path)
    if not os.path.isdir(folder):
        raise ShapeSpaceError(f"cannot write {path}: the folder {folder} does not exist", ErrorCode.UNWRITABLE)
    if os.path.isdir(path):
        raise ShapeSpaceError(f"cannot write {path}: it is a folder", ErrorCode.NOT_A_FILE)
    if _read_only(folder) or not _can_create_in(folder):
        raise ShapeSpaceError(f"cannot write {path}: the folder {folder} is read-only", ErrorCode.UNWRITABLE)
    if os.path.exists(path) and _read_only(path):
        raise ShapeSpaceError(f"cannot write {path}: the file is read-only", ErrorCode.UNWRITABLE)
    for other in inputs:
        if other and os.path.exists(other) and os.path.exists(path) and os.path.samefile(other, path):
            raise ShapeSpaceError(f"{path} is an input of this export; choose another output file",
                                  ErrorCode.OVERWRITE)
    return path


def _read_only(path: str) -> bool:
    """Marked read-only: no write permission for its owner, group or others (honoured even for root, who
    could write anyway), or not writable for this user."""
    return not (os.stat(path).st_mode & 0o222) or not os.access(path, os.W_OK)


def _can_create_in(folder: str) -> bool:
    """A file can really be created in ``folder`` (a read-only file system fails here)."""
    try:
        fd, probe = tempfile.mkstemp(prefix=".shapespace-probe-", dir=folder)
    except OSError:
        return False
    os.close(fd)
    os.remove(probe)
    return True
