"""The one check of an output file path, made before any work (no Blender: plain files only).

Every writer of ShapeSpace — the command line's ``--out``/``--report``, the export, the pose-space point
cache, the face-space coherence image — asks :func:`check_output_file` where it may write, so every one
refuses the same things with the same one-line messages, and nothing is lost: an input is never
overwritten, nor a file of another kind, nor a folder.
"""
from __future__ import annotations

import os
import stat
import tempfile
from collections.abc import Callable, Iterable

from .errors import ErrorCode
from .result import ShapeSpaceError

__all__ = ["BLEND_EXTENSIONS", "check_output_file", "same_file"]

#: A .blend file and Blender's backup of it: never the destination of anything but a saved .blend.
BLEND_EXTENSIONS = (".blend", ".blend1")


def same_file(a: str, b: str) -> bool:
    """Whether two paths name the same file (or the same absolute path when either does not exist)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.normcase(os.path.abspath(a)) == os.path.normcase(os.path.abspath(b))


def check_output_file(path: str, *, flag: str = "", what: str = "a file", extensions: tuple = (),
                      blend_ok: bool = False, inputs: Iterable[str] = (),
                      replaceable: Callable[[str], bool] | None = None, replace_hint: str = "choose another file",
                      overwrite: bool = False, devices: bool = False) -> str:
    """The absolute path to write ``path`` to, checked before any work; else one line naming the culprit.

    Checked in this order (message ``"<flag> <path>: <problem>"``, or ``"<path>: <problem>"`` without a flag):

    ====================================================================  ===============
    refused                                                               code
    ====================================================================  ===============
    an empty path                                                         ``usage``
    an extension not in ``extensions`` (when given)                       ``format``
    a ``.blend``/``.blend1`` name (unless ``blend_ok``)                   ``overwrite``
    a folder                                                              ``not_a_file``
    a folder that does not exist                                          ``unwritable``
    an existing file that is not a regular file (unless ``devices``)      ``not_a_file``
    one of ``inputs`` (the open .blend, a source file, …)                 ``overwrite``
    an existing file ``replaceable`` refuses (unless ``overwrite``)       ``overwrite``
    a read-only folder or file, or one no file can be created in          ``unwritable``
    ====================================================================  ===============

    Parameters
    ----------
    path : str
        The destination (``~`` expanded, made absolute against the working folder).
    flag : str
        How messages name the destination (``"--out"``); empty: by its path only.
    what : str
        What the file is (``"a PNG image"``, ``"a point cache"``, ``"a gltf file"``), for messages.
    extensions : tuple of str
        Lower-case extensions one of which the path must end in; empty: any.
    blend_ok : bool
        The destination may be a .blend file (a saved .blend, or a name the caller checks itself).
    inputs : iterable of str
        Files the caller reads: never written (empty entries are skipped).
    replaceable : callable(str) -> bool, optional
        Whether an existing regular file may be replaced (it is of the same kind); ``None``: any may.
    replace_hint : str
        What to do instead, said after ``exists and is not <what>``.
    overwrite : bool
        Replace an existing file even when ``replaceable`` refuses it (inputs stay refused).
    devices : bool
        Accept an existing device or pipe (``/dev/stdout``), proved writable by opening it for appending.

    Returns
    -------
    str
        The absolute, normalised path.
    """
    subject = f"{flag} {path}" if flag else str(path)
    if not path:
        raise ShapeSpaceError(f"{flag or 'output file'}: give a file name", ErrorCode.USAGE)
    full = os.path.normpath(os.path.abspath(os.path.expanduser(path)))
    ext = os.path.splitext(full)[1].lower()
    if extensions and ext not in extensions:
        raise ShapeSpaceError(f"{subject}: {what} must end in {' or '.join(extensions)}", ErrorCode.FORMAT)
    if not blend_ok and ext in BLEND_EXTENSIONS:
        raise ShapeSpaceError(f"{subject}: is a .blend file; give {what}", ErrorCode.OVERWRITE)
    if os.path.isdir(full):
        raise ShapeSpaceError(f"{subject}: is a folder; give a file name", ErrorCode.NOT_A_FILE)
    folder = os.path.dirname(full)
    if not os.path.isdir(folder):
        raise ShapeSpaceError(f"{subject}: the folder {folder} does not exist", ErrorCode.UNWRITABLE)
    exists = os.path.lexists(full)
    regular = not exists or (os.path.exists(full) and stat.S_ISREG(os.stat(full).st_mode))
    if exists and not regular and not devices:
        raise ShapeSpaceError(f"{subject}: is not a regular file", ErrorCode.NOT_A_FILE)
    for source in inputs:
        if source and same_file(full, source):
            raise ShapeSpaceError(f"{subject}: would overwrite the input {source}", ErrorCode.OVERWRITE)
    if exists and regular and not overwrite and replaceable is not None and not replaceable(full):
        raise ShapeSpaceError(f"{subject}: exists and is not {what}; {replace_hint}", ErrorCode.OVERWRITE)
    _check_writable(subject, full, folder, exists and not regular)
    return full


def _check_writable(subject: str, path: str, folder: str, device: bool) -> None:
    """Refuse a destination that cannot be written now (a device is opened for appending)."""
    if device:
        try:
            with open(path, "ab"):
                pass
        except OSError as exc:
            raise ShapeSpaceError(f"{subject}: cannot be written ({exc.strerror or exc})",
                                  ErrorCode.UNWRITABLE) from None
        return
    if _read_only(folder) or not _can_create_in(folder):
        raise ShapeSpaceError(f"{subject}: the folder {folder} is read-only", ErrorCode.UNWRITABLE)
    if os.path.exists(path) and _read_only(path):
        raise ShapeSpaceError(f"{subject}: the file is read-only", ErrorCode.UNWRITABLE)


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
