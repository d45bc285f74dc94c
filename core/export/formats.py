"""The export formats, what each can carry, and checks on the output path (before any work is done)."""
from __future__ import annotations

import os
from dataclasses import dataclass

from ..errors import ErrorCode
from ..paths import check_output_file
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
    """The absolute output path of an export in ``fmt``, checked before anything is baked.

    :func:`core.paths.check_output_file` with the format's extensions (code ``format`` for another one):
    any existing file that is not one of ``inputs`` (the open .blend, a source file) is replaced.
    """
    return check_output_file(path, what=f"a {fmt.name} file", extensions=fmt.extensions, inputs=inputs)
