"""Where the command line writes: checked before any work, written without half-files, never onto an input.

Rules (``--help`` and the README say the same):

- every output of a command (``--out``, ``--report``) is checked before anything is loaded or computed, by one
  call (:func:`check_outputs`): its folder must exist and be writable, it must not be a folder, it must not be
  another output of the same command, and it must not be one of the command's inputs (the opened or
  ``--target`` .blend, an ``info`` file, a ``--source`` file, a take's report) — the one exception is
  ``retarget``/``transfer --out`` onto the opened .blend with ``--overwrite`` (Blender keeps the old one as
  ``.blend1``);
- an existing regular file is replaced only if it is of the same kind (a JSON report for JSON, a .blend
  for ``--out``; an exported file of any content), or with ``--overwrite``;
- JSON goes to a temporary file beside the destination, moved into place only when everything else
  (the .blend) is saved; any write failure is one ``shapespace: error:`` line.
"""
from __future__ import annotations

import contextlib
import os
import stat
import tempfile

from ..core.errors import ErrorCode
from ..core.paths import check_output_file, same_file
from ..core.result import ShapeSpaceError

__all__ = ["Output", "check_output", "check_outputs", "same_file"]

_BLEND_MAGIC = (b"BLENDER", b"\x28\xb5\x2f\xfd", b"\x1f\x8b")     # plain, zstd- and gzip-compressed


#: What each kind of output is, for messages.
_KINDS = {"json": "a JSON report", "blend": "a .blend file", "export": "an exported file"}


def _looks_like(path: str, kind: str) -> bool:
    try:
        with open(path, "rb") as fh:
            head = fh.read(64)
    except OSError:
        return False
    if not head.strip():
        return True                                   # an empty file holds nothing to lose
    if kind == "json":
        return head.lstrip()[:1] in (b"{", b"[")
    if kind == "blend":
        return head.startswith(_BLEND_MAGIC)
    return True                                       # an exported file (glTF, FBX, Alembic): replaced as such


class Output:
    """One checked destination: ``flag`` (for messages), ``path`` as given, ``kind`` (``json``, ``blend`` or
    ``export``)."""

    def __init__(self, flag: str, path: str, kind: str):
        self.flag, self.path, self.kind = flag, path, kind
        self.abspath = os.path.abspath(path)
        self.regular = not os.path.exists(self.abspath) or stat.S_ISREG(os.stat(self.abspath).st_mode)
        self._pending = None                          # a written temporary JSON file, not yet in place

    def fail(self, what: str, code: ErrorCode = ErrorCode.UNWRITABLE) -> ShapeSpaceError:
        return ShapeSpaceError(f"{self.flag} {self.path}: {what}", code)

    def stage_text(self, text: str) -> None:
        """Write ``text`` to a temporary file beside the destination (a device is written at :meth:`commit`)."""
        if not self.regular:
            self._pending = text
            return
        try:
            fd, tmp = tempfile.mkstemp(dir=os.path.dirname(self.abspath), prefix=".shapespace-", suffix=".tmp")
            with os.fdopen(fd, "w", encoding="utf-8") as fh:
                fh.write(text)
        except OSError as exc:
            raise self.fail(f"cannot be written ({exc.strerror or exc})") from None
        self._pending = tmp

    def commit(self) -> None:
        """Move the staged JSON into place."""
        try:
            if self.regular:
                os.replace(self._pending, self.abspath)
            else:
                with open(self.abspath, "w", encoding="utf-8") as fh:
                    fh.write(self._pending)
        except OSError as exc:
            raise self.fail(f"cannot be written ({exc.strerror or exc})") from None
        finally:
            self._pending = None

    def discard(self) -> None:
        """Remove a staged file that will not be committed."""
        if self.regular and self._pending:
            with contextlib.suppress(OSError):
                os.remove(self._pending)
        self._pending = None


def check_output(flag: str, path: str | None, kind: str, inputs: list, overwrite: bool = False,
                 opened_blend: str = "") -> Output | None:
    """The destination of ``flag`` checked against the rules of this module (``None`` when not given).

    Parameters
    ----------
    flag : str
        ``--out`` or ``--report`` (named in messages).
    path : str or None
    kind : {"json", "blend", "export"}
    inputs : list of str
        Files the command reads.
    overwrite : bool
        ``--overwrite``: replace a file of another kind, or save a .blend onto ``opened_blend``.
    opened_blend : str
        The .blend the command works on (may be saved in place with ``overwrite``).
    """
    if path is None:
        return None
    if kind == "blend" and opened_blend and not overwrite and path and same_file(path, opened_blend):
        raise ShapeSpaceError(f"{flag} {path}: would overwrite the input {opened_blend} (give --overwrite to save "
                              "into it)", ErrorCode.OVERWRITE)
    in_place = kind == "blend" and overwrite and opened_blend
    read = [p for p in inputs if not (in_place and p and same_file(p, opened_blend))]
    check_output_file(path, flag=flag, what=_KINDS[kind], blend_ok=True, inputs=read, overwrite=overwrite,
                      replaceable=lambda full: _looks_like(full, kind), replace_hint="give --overwrite to replace it",
                      devices=True)
    return Output(flag, path, kind)


def check_outputs(outputs, inputs: list, overwrite: bool = False, opened_blend: str = "") -> list:
    """Every output of one command checked before any work: each against every input (:func:`check_output`)
    and against every other output (two flags naming one file are refused, whatever ``overwrite`` says).

    Parameters
    ----------
    outputs : sequence of (flag, path or None, kind)
        The command's destinations, in the order they are named in messages.
    inputs, overwrite, opened_blend
        As for :func:`check_output`.

    Returns
    -------
    list of Output or None
        One per entry of ``outputs`` (``None`` where no path was given).
    """
    given = [(flag, path) for flag, path, _ in outputs if path]
    for k, (flag, path) in enumerate(given):
        for first_flag, first in given[:k]:
            if same_file(first, path):
                raise ShapeSpaceError(f"{flag} {path}: is also the {first_flag} file; give two files",
                                      ErrorCode.OVERWRITE)
    return [check_output(flag, path, kind, inputs, overwrite, opened_blend) for flag, path, kind in outputs]
