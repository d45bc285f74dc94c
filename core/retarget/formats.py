"""Recordings of the face-capture apps, each read into the Live Link Face reader's :class:`~.capture.WeightStream`.

Every reader keeps the Live Link Face CSV reader's contract (:mod:`.capture`): a regular file of at most
:data:`~.capture.MAX_FILE_BYTES` opened without blocking (a FIFO or device is refused), UTF-8 text, one-line
:class:`~core.result.ShapeSpaceError` messages naming the line (or frame) and field, channels matched to
ARKit by name (:func:`core.names.canonical_name`), NaN cells filled from the neighbouring frames, samples
sorted and de-duplicated, gaps and takes checked (:func:`~.capture.finish_stream`).  Times are the source's
own — a variable rate is resampled to the scene's by :func:`~.capture.resample` like a CSV take.  Head and
eye rotations, where the format records them, become ``rotations`` (f, 9) in the live frames' convention
(``(yaw, pitch, roll)`` radians: :class:`core.live.LiveFrame`), through the live decoders' own conversions.

Formats (their public descriptions; no code was copied):

- ``facecap_txt`` — Face Cap's TXT export (Bannaflak, https://www.bannaflak.com/face-cap/), as its public
  importers document it (Thomas Larsson's DAZ importer ``import_facecap``; Faceit's ``FaceCapImporter``)::

      info,…                                   metadata (ignored)
      bs,browInnerUp,…,tongueOut               the blendshape names, in the column order of the keys
      k,T,hx,hy,hz,hrx,hry,hrz,elx,ely,erx,ery,w1,…,wN

  ``T`` milliseconds from the start, head position, head Euler degrees (x pitch, y yaw, z roll), left and
  right eye Euler degrees (x pitch, y yaw) — the conventions of Face Cap's live OSC ``/HR``, ``/ELR``,
  ``/ERR`` (:class:`core.live.FaceCapAssembler`).  Without a ``bs`` line the keys are in Face Cap's
  order (:data:`core.names.FACECAP_52`).
- ``ifacialmocap`` — iFacialMocap's frame text (https://www.ifacialmocap.com/for-developer/):
  ``name-value|…|=head#rx,ry,rz,px,py,pz|rightEye#rx,ry,rz|leftEye#rx,ry,rz|`` (``name&value`` in its v2
  mode), values 0–100, angles in degrees; its TCP stream ends each frame with ``___iFacialMocap``.  A
  recording is those frames one per line (or the TCP stream as received).  The text carries no time: frames
  are at the app's documented 60 fps.
- ``audio2face_json`` — NVIDIA Audio2Face's blendshape-weight JSON export (Audio2Face manual, "Blendshape
  Conversion", export format ``.json``): ``exportFps``, ``numPoses``, ``numFrames``, ``facsNames`` (the
  poses' names) and ``weightMat`` (``numFrames`` rows of ``numPoses`` weights), frame ``k`` at
  ``k / exportFps``.
- ``mediapipe_json`` / ``mediapipe_csv`` — MediaPipe Face Landmarker blendshapes (its ``face_blendshapes``
  result: categories with ``category_name`` and ``score``; the 52 categories are ``_neutral``, ignored, and
  51 ARKit names).  MediaPipe writes no file: a recording is the per-video-frame results with the
  ``timestamp_ms`` given to ``detect_for_video`` — JSON: a list of ``{"timestamp_ms": t,
  "face_blendshapes": [[{"category_name": …, "score": …}, …]]}`` (the first face; ``[]`` when no face was
  found: filled from the neighbours), or ``{"frames": [...]}``; CSV: a ``timestamp_ms`` column and one
  column per category name.
- ``llf_csv`` — the Live Link Face CSV (:func:`~.capture.read_live_link_csv`, with its head and eye
  columns).

The kind is detected from the content (:func:`detect_kind`), never from the file's extension alone.
"""
from __future__ import annotations

import gc
import json
import math
import os
import re
import warnings
from array import array as array_of
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from operator import itemgetter

import numpy as np

from ..errors import ErrorCode
from ..headpose import eye_ypr_from_degrees, ypr_from_degrees
from ..names import ARKIT_52, FACECAP_52
from ..result import Issue, ShapeSpaceError
from . import capture
from .capture import (
    MAX_ABS_WEIGHT,
    ROTATION_CHANNELS,
    WeightStream,
    _channel_columns,
    _csv_rows,
    _parse,
    capture_path,
    finish_stream,
    plain_rows,
    read_capture_chunks,
    read_capture_text,
)

__all__ = ["KINDS", "detect_kind", "read_capture", "parse_capture", "describe_stream", "IFACIALMOCAP_FPS",
           "MAX_ABS_DEGREES", "MAX_JSON_BYTES"]

#: Kinds of capture recording, with what users call them.
KINDS = {"llf_csv": "Live Link Face CSV", "facecap_txt": "Face Cap TXT", "ifacialmocap": "iFacialMocap recording",
         "audio2face_json": "Audio2Face blendshape JSON", "mediapipe_json": "MediaPipe blendshapes JSON",
         "mediapipe_csv": "MediaPipe blendshapes CSV"}

#: iFacialMocap's frame rate (its frames carry no time).
IFACIALMOCAP_FPS = 60.0
#: Largest angle magnitude read, in degrees: beyond it a cell is damaged.
MAX_ABS_DEGREES = 3600.0
#: Largest head position magnitude read (Face Cap, iFacialMocap): beyond it a cell is damaged.
MAX_ABS_POSITION = 1e6
#: Largest JSON text parsed (its numbers become Python objects: ~10× the text in memory).
MAX_JSON_BYTES = 64 * 2 ** 20
#: Largest number of blendshape columns a recording may have.
MAX_CHANNELS = 1024

_IFM_END = "___iFacialMocap"
_SNIFF = 65536


# ------------------------------------------------------------------ detection and dispatch
def detect_kind(text: str) -> str:
    """The kind of capture recording ``text`` is (a key of :data:`KINDS`), from its content.

    Raises
    ------
    ShapeSpaceError
        ``unsupported_file`` when it is none of them (the message lists the kinds read).
    """
    head = text[:_SNIFF].lstrip("\ufeff \t\r\n")
    if not head:
        raise ShapeSpaceError("the file is empty", ErrorCode.EMPTY)
    if head[0] in "{[":
        if '"weightMat"' in head or '"facsNames"' in head:
            return "audio2face_json"
        if "blendshapes" in head or "category_name" in head or '"frames"' in head:
            return "mediapipe_json"
    first = head.split("\n", 1)[0].strip()
    if first.startswith(("info,", "bs,", "k,")):
        return "facecap_txt"
    if "=head#" in head or _IFM_END in head:
        return "ifacialmocap"
    cells = [c.strip().strip('"') for c in first.split(",")]
    if "Timecode" in cells:
        return "llf_csv"
    if "timestamp_ms" in cells:
        return "mediapipe_csv"
    if len(cells) > 1:
        raise ShapeSpaceError("the CSV has no Timecode column (Live Link Face) nor timestamp_ms (MediaPipe): not a "
                              "capture recording ShapeSpace reads", ErrorCode.NO_TIMECODE)
    raise ShapeSpaceError("not a capture recording ShapeSpace reads (" + ", ".join(KINDS.values()) + ")",
                          ErrorCode.UNSUPPORTED_FILE)


def read_capture(source: str | os.PathLike, required: Sequence[str] = ARKIT_52) -> WeightStream:
    """Read any supported capture recording (path or text) into a :class:`~.capture.WeightStream`.

    The kind is detected from the content (:func:`detect_kind`); the Live Link Face CSV is read with its head
    and eye columns; a MediaPipe JSON list of frames is read from the file piece by piece (never whole).  Every
    failure is a one-line :class:`ShapeSpaceError`; from a file its message starts with the path.
    """
    path = capture_path(source)
    stream = None if path is None else _read_mediapipe_file(path, required)
    if stream is not None:
        return stream
    text, label = read_capture_text(source)
    try:
        return parse_capture(text, required)
    except ShapeSpaceError as exc:
        if label is None:
            raise
        raise ShapeSpaceError(f"{label}: {exc}", exc.code) from None


class _SourceError(ShapeSpaceError):
    """A failure reading the file itself (its message names the file already)."""


def _source_pieces(pieces: Iterator[str]) -> Iterator[str]:
    try:
        yield from pieces
    except ShapeSpaceError as exc:
        raise _SourceError(str(exc), exc.code) from None


def _read_mediapipe_file(path: str, required: Sequence[str]) -> WeightStream | None:
    """The stream of the MediaPipe JSON list of frames at ``path``, read piece by piece, or ``None`` when the file
    is something else or cannot be read (:func:`read_capture` then reads it whole and says why)."""
    pieces = _source_pieces(read_capture_chunks(path))
    src = _Text("", pieces)
    try:
        try:
            src.ahead(0, _SNIFF)
            head = src.text[:_SNIFF].lstrip("\ufeff \t\r\n")
            if not head.startswith("[") or detect_kind(head) != "mediapipe_json":
                return None
        except ShapeSpaceError:
            return None
        try:
            stream = _mediapipe_json(src, required)
        except _SourceError as exc:
            raise ShapeSpaceError(str(exc), exc.code) from None
        except ShapeSpaceError as exc:
            try:                                      # a file that is not UTF-8 further on is refused as such
                for _ in pieces:
                    pass
            except _SourceError as bad:
                raise ShapeSpaceError(str(bad), bad.code) from None
            raise ShapeSpaceError(f"{path}: {exc}", exc.code) from None
    finally:
        pieces.close()
    stream.kind = "mediapipe_json"
    return stream


def parse_capture(text: str, required: Sequence[str] = ARKIT_52, kind: str | None = None) -> WeightStream:
    """The stream of a recording's text (``kind``: detected when None); errors name the line, not the file."""
    kind = kind or detect_kind(text)
    if kind == "llf_csv":
        stream = _parse(text, required, 60.0, True)
    elif kind == "facecap_txt":
        stream = _facecap(text, required)
    elif kind == "ifacialmocap":
        stream = _ifacialmocap(text, required)
    elif kind == "audio2face_json":
        stream = _audio2face_text(text, required)
    elif kind == "mediapipe_json":
        stream = _mediapipe_json(text, required)
    elif kind == "mediapipe_csv":
        stream = _mediapipe_csv(text, required)
    else:
        raise ShapeSpaceError(f"unknown capture kind {kind!r}", ErrorCode.UNSUPPORTED_FILE)
    stream.kind = kind
    return stream


def describe_stream(stream: WeightStream) -> dict:
    """What a recording holds, as JSON-ready data: kind, channels, rate, duration, head / eye channels."""
    steps = np.diff(stream.times)
    median = float(np.median(steps)) if steps.size else 0.0
    rot = stream.rotations
    moving = [] if rot is None else [c for c, col in zip(ROTATION_CHANNELS, rot.T) if np.ptp(col) > 0]
    return {"kind": stream.kind, "format": KINDS.get(stream.kind, stream.kind), "frames": int(stream.times.size),
            "channels": len(stream.names), "channel_names": list(stream.names),
            "rate": stream.rate if stream.rate is not None else (round(1.0 / median, 3) if median > 0 else None),
            "measured_rate": round(1.0 / median, 3) if median > 0 else None,
            "variable_rate": bool(steps.size and (steps.max() - steps.min()) > 0.25 * median),
            "duration_s": float(stream.times[-1]), "head_eye_channels": list(ROTATION_CHANNELS) if rot is not None
            else [], "head_eye_moving": moving, "start_timecode": stream.start_timecode,
            "issues": [i.message for i in stream.issues]}


# ------------------------------------------------------------------ shared cell parsing
def _number(text: str, where: str, limit: float) -> float:
    """One numeric cell (NaN when empty); damaged cells refused naming ``where`` (line and field)."""
    cell = text.strip()
    if not cell:
        return math.nan
    try:
        value = float(cell)
    except ValueError:
        raise ShapeSpaceError(f"{where}: {cell[:40]!r} is not a number", ErrorCode.NOT_NUMBER) from None
    if math.isfinite(value) and abs(value) > limit:
        raise ShapeSpaceError(f"{where}: {cell[:40]} is beyond ±{limit:g}: a damaged value", ErrorCode.RANGE)
    return value


def _columns(names: Sequence[str], required: Sequence[str]) -> tuple:
    """``(columns, names, issues)`` of the wanted ARKit channels among ``names`` (``_neutral`` dropped)."""
    if len(names) > MAX_CHANNELS:
        raise ShapeSpaceError(f"the recording names {len(names)} channels (at most {MAX_CHANNELS})",
                              ErrorCode.TOO_LARGE)
    header = [str(n).strip() for n in names]
    header = ["BlendShapeCount" if h == "_neutral" else h for h in header]     # skipped like LLF's count
    return _channel_columns(header, -1, required)


def _frames(values: array_of, count: int, width: int) -> np.ndarray:
    return np.frombuffer(values, dtype=np.float64).copy().reshape(count, width)


# ------------------------------------------------------------------ Face Cap TXT
def _facecap(text: str, required: Sequence[str]) -> WeightStream:
    names, t, w, pose, lines = _facecap_plain(text) or _facecap_cells(text)
    cols, kept, issues = _columns(names, required)
    rot = np.concatenate([ypr_from_degrees(pose[:, 3:6]), eye_ypr_from_degrees(pose[:, 6:8]),
                          eye_ypr_from_degrees(pose[:, 8:10])], axis=1)
    _check_time(t)
    return finish_stream(t, w[:, cols], kept, lines, issues, rot, "facecap_txt")


#: Face Cap's value limits per key field after ``k``: time (ms), head position, head and eye angles (degrees).
_FACECAP_LIMITS = np.array([1e12] + [MAX_ABS_POSITION] * 3 + [MAX_ABS_DEGREES] * 7)


def _facecap_plain(text: str) -> tuple | None:
    """:func:`_facecap_cells`'s result in one pass for a recording of plain keys (:func:`~.capture.plain_rows`:
    every cell a number, every key line ``k,…``), else ``None``."""
    if "\r" in text:
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    at = 0 if text.startswith("k,") else text.find("\nk,") + 1
    if at < 0 or (at == 0 and not text.startswith("k,")):
        return None
    names = list(FACECAP_52)
    for line in text[:at].split("\n"):
        line = line.strip()
        if line.startswith("bs,"):
            names = [n.strip() for n in line.split(",")[1:]]
        elif line and not line.startswith("info,"):
            return None
    body = text[at:].rstrip() + "\n"
    if body.count("\nk,") != body.count("\n") - 1:
        return None                                            # a line that is not a key
    a = plain_rows(("\n" + body).replace("\nk,", "\n")[1:], 11 + len(names))
    if a is None or np.any(np.abs(a[:, :11]) > _FACECAP_LIMITS) or np.any(np.abs(a[:, 11:]) > MAX_ABS_WEIGHT):
        return None
    first = text[:at].count("\n") + 1
    return names, a[:, 0] / 1000.0, a[:, 11:], a[:, 1:11], np.arange(first, first + a.shape[0])


def _facecap_cells(text: str) -> tuple:
    """``(names, times (f,), weights (f, n), head / eye fields (f, 10), lines)`` read cell by cell, naming the
    line and field of anything wrong."""
    names, width = list(FACECAP_52), None
    times, values, poses, lines = array_of("d"), array_of("d"), array_of("d"), array_of("q")
    for i, line in _numbered_lines(text):
        if line.startswith("info,"):
            continue
        if line.startswith("bs,"):
            if lines:
                raise ShapeSpaceError(f"line {i}: the blendshape names (bs,…) come after the first key",
                                      ErrorCode.CORRUPT_FILE)
            names = [n.strip() for n in line.split(",")[1:]]
            continue
        if not line.startswith("k,"):
            raise ShapeSpaceError(f"line {i}: {line[:30]!r} is neither info, bs nor a key (k,…): not a Face Cap "
                                  "TXT line", ErrorCode.CORRUPT_FILE)
        cells = line.split(",")
        width = width or len(names)
        if len(cells) != 12 + width:
            raise ShapeSpaceError(f"line {i} has {len(cells) - 12} blendshape values, the recording names {width}",
                                  ErrorCode.RAGGED)
        times.append(_number(cells[1], f"line {i}, field 2 (time ms)", 1e12) / 1000.0)
        poses.extend([_number(c, f"line {i}, field {k + 3} (head/eye)", MAX_ABS_DEGREES if k >= 3 else
                              MAX_ABS_POSITION) for k, c in enumerate(cells[2:12])])
        values.extend([_number(c, f"line {i}, field {k + 13} ({names[k]})", MAX_ABS_WEIGHT)
                       for k, c in enumerate(cells[12:])])
        lines.append(i)
    if not lines:
        raise ShapeSpaceError("the Face Cap recording has no keys (k,… lines)", ErrorCode.TOO_SHORT)
    t = np.frombuffer(times, dtype=np.float64).copy()
    return (names, t, _frames(values, t.size, len(names)), _frames(poses, t.size, 10),
            np.frombuffer(lines, dtype=np.int64).copy())


def _numbered_lines(text: str):
    """``(line number, stripped line)`` of every non-blank line (any line ending)."""
    if "\r" in text:
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    for i, line in enumerate(text.split("\n"), start=1):
        line = line.strip()
        if line:
            yield i, line


def _check_time(t: np.ndarray) -> None:
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise ShapeSpaceError(f"key {int(bad[0]) + 1}: its time is missing or not finite", ErrorCode.TIMECODE)


# ------------------------------------------------------------------ iFacialMocap
_IFM_POSES = {"=head#": 0, "head#": 0, "rightEye#": 6, "leftEye#": 9}
_IFM_SIZES = {0: 6, 6: 3, 9: 3}


def _ifacialmocap(text: str, required: Sequence[str]) -> WeightStream:
    frames = text.replace(_IFM_END, "\n") if _IFM_END in text else text
    names, w, pose, lines = _ifm_plain(frames) or _ifm_cells(frames)
    cols, kept, issues = _columns(names, required)
    # iFacialMocap sends head and eyes as Euler degrees (x pitch, y yaw, z roll), like its live packets
    rot = np.concatenate([ypr_from_degrees(pose[:, 0:3]), ypr_from_degrees(pose[:, 9:12]),
                          ypr_from_degrees(pose[:, 6:9])], axis=1)
    t = np.arange(w.shape[0]) / IFACIALMOCAP_FPS
    stream = finish_stream(t, np.ascontiguousarray(w[:, cols]), kept, lines, issues, rot, "ifacialmocap")
    stream.rate = IFACIALMOCAP_FPS
    return stream


_POSE_LIMITS = np.array([MAX_ABS_DEGREES] * 3 + [MAX_ABS_POSITION] * 3 + [MAX_ABS_DEGREES] * 6)


def _ifm_plain(frames: str) -> tuple | None:
    """:func:`_ifm_cells`'s result for a recording whose frames all repeat the first one's fields (names,
    separators and poses, in order) with plain numbers, read without a per-field Python step
    (:func:`_ifm_values`, a chunk of lines at a time); ``None`` otherwise."""
    if "\r" in frames:
        frames = frames.replace("\r\n", "\n").replace("\r", "\n")
    lead, stop = 0, len(frames)                     # the text is not copied: blank lines around it skipped
    while lead < stop and frames[lead] == "\n":
        lead += 1
    while stop > lead and frames[stop - 1] == "\n":
        stop -= 1
    first = frames[lead:frames.find("\n", lead, stop) % (stop + 1)]
    fields = _ifm_fields(first) if first else None
    if fields is None:
        return None
    names, prefixes, targets, counts = fields
    parts, at = [], lead
    while at < stop:
        end = frames.rfind("\n", at, min(stop, at + capture.PLAIN_CHUNK)) + 1 or frames.find("\n", at, stop) + 1 \
            or stop
        try:
            raw = np.frombuffer((frames[at:end] if end < stop else frames[at:stop] + "\n").encode("ascii"),
                                dtype=np.uint8)
        except UnicodeEncodeError:
            return None
        part = _ifm_values(raw, prefixes, counts, first.endswith("|"))
        if part is None:
            return None
        parts.append(part)
        at = end
    a = parts[0] if len(parts) == 1 else np.concatenate(parts)
    w_cols = [j for j, (kind, _) in enumerate(targets) if kind == "w"]
    p_cols = [j for _, j in sorted((k, j) for j, (kind, k) in enumerate(targets) if kind == "pose")]
    w, pose = a[:, w_cols], a[:, p_cols]
    if np.any(np.abs(w) > 100.0 * MAX_ABS_WEIGHT) or np.any(np.abs(pose) > _POSE_LIMITS):
        return None
    return names, w / 100.0, pose, np.arange(lead + 1, lead + 1 + a.shape[0])


def _ifm_fields(first: str) -> tuple | None:
    """``(names, prefixes, targets, counts)`` of a frame's fields: each field's text before its value(s), where
    each value goes (``("w", column)`` or ``("pose", index)``) and how many values it holds; ``None`` when
    the frame is not plain (an empty, padded or repeated field, a missing pose)."""
    try:
        names, _, _, _ = _ifm_cells(first)
    except ShapeSpaceError:
        return None
    prefixes, targets, counts = [], [], []
    for field in first.rstrip("|").split("|"):
        tag = next((t for t in _IFM_POSES if field.startswith(t)), None)
        if tag is not None:
            prefixes.append(tag)
            counts.append(_IFM_SIZES[_IFM_POSES[tag]])
            targets += [("pose", _IFM_POSES[tag] + k) for k in range(counts[-1])]
        else:
            name, sep, _ = field.partition("&") if "&" in field else field.partition("-")
            if field != field.strip() or name not in names:
                return None                              # an empty or padded field: read cell by cell
            prefixes.append(name + sep)
            counts.append(1)
            targets.append(("w", names.index(name)))
    if len(set(prefixes)) != len(prefixes) or sorted(k for kind, k in targets if kind == "pose") != list(range(12)):
        return None
    return names, prefixes, targets, counts


def _ifm_values(raw: np.ndarray, prefixes: list, counts: list, trailing: bool) -> np.ndarray | None:
    """The values (lines, Σ counts) of whole lines ``raw`` (ASCII bytes ending in a line break) when every line
    is the fields ``prefix + value(s)`` in order, separated by ``|`` (one more before the line break with
    ``trailing``), a pose's values by ``,``, every value a plain number; ``None`` otherwise."""
    if np.any((raw == 32) | (raw == 9) | (raw == 11) | (raw == 12) | (raw == 0)):
        return None                                       # white space or NUL: read cell by cell
    per = len(prefixes) + trailing                        # bounds per line: the | after each field, the break
    ends = np.flatnonzero((raw == 124) | (raw == 10))
    if ends.size % per:
        return None
    bounds = ends.reshape(-1, per)
    kinds = raw[bounds]
    if not (np.all(kinds[:, :-1] == 124) and np.all(kinds[:, -1] == 10)):
        return None
    if trailing and np.any(bounds[:, -1] != bounds[:, -2] + 1):
        return None                                       # text after the last |
    starts = np.empty((bounds.shape[0], len(prefixes)), dtype=np.int64)
    starts[0, 0] = 0
    starts[1:, 0] = bounds[:-1, -1] + 1
    starts[:, 1:] = bounds[:, :len(prefixes) - 1] + 1
    keep = np.ones(raw.size, dtype=bool)
    for j, prefix in enumerate(prefixes):
        want = np.frombuffer(prefix.encode("ascii"), dtype=np.uint8)
        if np.any(bounds[:, j] - starts[:, j] <= want.size):
            return None                                   # a field without its value
        at = starts[:, j, None] + np.arange(want.size)
        if not np.array_equal(raw[at], np.broadcast_to(want, at.shape)):
            return None                                   # another name (or order) than the first frame's
        keep[at.ravel()] = False
    commas = np.bincount(np.searchsorted(ends, np.flatnonzero(raw == 44)), minlength=ends.size).reshape(bounds.shape)
    if np.any(commas[:, :len(prefixes)] != np.array(counts) - 1) or np.any(commas[:, len(prefixes):]):
        return None                                       # a pose with another number of values
    if trailing:
        keep[bounds[:, -2]] = False
    text = raw.copy()
    text[bounds.ravel()] = 44
    text = text[keep][:-1].tobytes()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            values = np.fromstring(text, sep=",")
        except (DeprecationWarning, ValueError):
            return None
    if values.size != bounds.shape[0] * sum(counts) or not np.isfinite(values).all():
        return None
    return values.reshape(bounds.shape[0], sum(counts))


def _ifm_cells(frames: str) -> tuple:
    """``(names, weights (f, n), poses (f, 12): head 6, right eye 3, left eye 3, lines)`` read field by field,
    naming the line and field of anything wrong."""
    column = {}                       # canonical name → column (first frame's order, then new names appended)
    names, rows, poses, lines = [], [], array_of("d"), array_of("q")
    for i, line in _numbered_lines(frames):
        row, pose = {}, [0.0] * 12
        for field in line.strip("\0").split("|"):
            field = field.strip()
            if not field:
                continue
            for tag, at in _IFM_POSES.items():
                if field.startswith(tag):
                    parts = field[len(tag):].split(",")
                    if len(parts) != _IFM_SIZES[at]:
                        raise ShapeSpaceError(f"frame {len(lines) + 1} (line {i}): {tag.strip('=#')} has "
                                              f"{len(parts)} numbers, expected {_IFM_SIZES[at]}", ErrorCode.RAGGED)
                    for k, p in enumerate(parts):
                        pose[at + k] = _number(p, f"line {i}, {tag.strip('=#')} value {k + 1}",
                                               MAX_ABS_POSITION if at == 0 and k >= 3 else MAX_ABS_DEGREES)
                    break
            else:
                name, sep, value = field.partition("&") if "&" in field else field.partition("-")
                if not sep or not name or len(name) > 64:
                    raise ShapeSpaceError(f"line {i}: field {field[:40]!r} is neither a blendshape (name-value) "
                                          "nor a pose (=head#, rightEye#, leftEye#)", ErrorCode.CORRUPT_FILE)
                if name not in column:
                    if len(column) >= MAX_CHANNELS:
                        raise ShapeSpaceError(f"line {i}: more than {MAX_CHANNELS} blendshape names",
                                              ErrorCode.TOO_LARGE)
                    column[name] = len(names)
                    names.append(name)
                row[column[name]] = _number(value, f"line {i}, {name}", 100.0 * MAX_ABS_WEIGHT) / 100.0
        if not row:
            raise ShapeSpaceError(f"line {i}: the frame has no blendshape (name-value|…)", ErrorCode.CORRUPT_FILE)
        rows.append(row)
        poses.extend(pose)
        lines.append(i)
    if not rows:
        raise ShapeSpaceError("the iFacialMocap recording has no frames", ErrorCode.TOO_SHORT)
    w = np.full((len(rows), len(names)), np.nan)
    for f, row in enumerate(rows):
        w[f, list(row)] = list(row.values())
    return names, w, _frames(poses, len(rows), 12), np.frombuffer(lines, dtype=np.int64).copy()


# ------------------------------------------------------------------ JSON (Audio2Face, MediaPipe)
def _json(text: str):
    if len(text) > MAX_JSON_BYTES:
        raise ShapeSpaceError(f"the JSON is {len(text) / 2 ** 20:.0f} MiB; capture JSON larger than "
                              f"{MAX_JSON_BYTES / 2 ** 20:.0f} MiB is refused (split the take)", ErrorCode.TOO_LARGE)
    try:
        return json.loads(text, parse_constant=lambda c: math.nan)
    except json.JSONDecodeError as exc:
        raise ShapeSpaceError(f"line {exc.lineno}, column {exc.colno}: not valid JSON ({exc.msg})",
                              ErrorCode.CORRUPT_FILE) from None
    except (RecursionError, ValueError) as exc:
        raise ShapeSpaceError(f"not readable JSON ({type(exc).__name__})", ErrorCode.CORRUPT_FILE) from None


def _field(data: dict, key: str, kind, what: str):
    if not isinstance(data, dict) or key not in data:
        raise ShapeSpaceError(f"the {what} has no {key!r} field", ErrorCode.CORRUPT_FILE)
    value = data[key]
    if not isinstance(value, kind) or isinstance(value, bool):
        raise ShapeSpaceError(f"the {what}'s {key!r} is a {type(value).__name__}", ErrorCode.CORRUPT_FILE)
    return value


def _weight_row(row, width: int, where: str) -> list:
    if not isinstance(row, list) or len(row) != width:
        size = len(row) if isinstance(row, list) else type(row).__name__
        raise ShapeSpaceError(f"{where} has {size} weights, expected {width}", ErrorCode.RAGGED)
    out = []
    for k, v in enumerate(row):
        if v is None:
            out.append(math.nan)
            continue
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ShapeSpaceError(f"{where}, weight {k + 1}: {str(v)[:40]!r} is not a number", ErrorCode.NOT_NUMBER)
        if math.isfinite(v) and abs(v) > MAX_ABS_WEIGHT:
            raise ShapeSpaceError(f"{where}, weight {k + 1}: {v:g} is beyond ±{MAX_ABS_WEIGHT:g}: a damaged value",
                                  ErrorCode.RANGE)
        out.append(float(v))
    return out


_A2F_MATRIX = re.compile(r'"weightMat"\s*:\s*(\[[\[\]0-9eE.+\-,\s]*\])')
_ROW_BREAK = re.compile(r"\]\s*,\s*\[")
_SPACE = re.compile(r"\s+")


def _audio2face_text(text: str, required: Sequence[str]) -> WeightStream:
    """An Audio2Face export: a ``weightMat`` of plain numbers read in one pass (:func:`~.capture.plain_rows`),
    the other fields by the json module; anything else parsed whole and checked cell by cell."""
    found = _A2F_MATRIX.search(text)
    if found is not None and found.group(1).count("[") == found.group(1).count("]"):
        try:
            data = _json(text[:found.start(1)] + "[]" + text[found.end(1):])
        except ShapeSpaceError:                  # not the whole matrix: the whole text names what is wrong
            return _audio2face(_json(text), required)
        names = data.get("facsNames") if isinstance(data, dict) else None
        matrix = found.group(1)
        matrix = _SPACE.sub("", matrix) if "\n" in matrix else matrix.strip()     # pretty-printed rows: one line
        if isinstance(names, list) and matrix.startswith("[[") and matrix.endswith("]]"):
            rows = plain_rows(_ROW_BREAK.sub("\n", matrix[2:-2]) + "\n", len(names))
            if rows is not None and not np.any(np.abs(rows) > MAX_ABS_WEIGHT):
                return _audio2face(data, required, rows)
    return _audio2face(_json(text), required)


def _audio2face(data, required: Sequence[str], rows: np.ndarray | None = None) -> WeightStream:
    what = "Audio2Face export"
    names = _field(data, "facsNames", list, what)
    if not all(isinstance(n, str) for n in names):
        raise ShapeSpaceError("the Audio2Face export's facsNames are not all names", ErrorCode.CORRUPT_FILE)
    fps = float(_field(data, "exportFps", (int, float), what))
    if not (math.isfinite(fps) and 0 < fps <= 1000):
        raise ShapeSpaceError(f"the Audio2Face export's exportFps is {fps:g}; it must lie in (0, 1000]",
                              ErrorCode.FPS)
    mat = _field(data, "weightMat", list, what) if rows is None else rows
    for key, expected in (("numPoses", len(names)), ("numFrames", len(mat))):
        stated = data.get(key, expected)
        if stated != expected:
            raise ShapeSpaceError(f"the Audio2Face export's {key} is {stated!r} but it holds {expected}",
                                  ErrorCode.RAGGED)
    cols, kept, issues = _columns(names, required)
    if not len(mat):
        raise ShapeSpaceError("the Audio2Face export has no frames", ErrorCode.TOO_SHORT)
    if rows is None:
        values = array_of("d")
        for f, row in enumerate(mat):
            values.extend(_weight_row(row, len(names), f"weightMat frame {f + 1}"))
        rows = _frames(values, len(mat), len(names))
    w = np.ascontiguousarray(rows[:, cols])
    t = np.arange(len(mat)) / fps
    stream = finish_stream(t, w, kept, np.arange(1, len(mat) + 1), issues, None, "audio2face_json")
    stream.rate = fps
    return stream


def _mediapipe_frame(frame, k: int) -> tuple:
    """``(timestamp ms, {category name: score})`` of one MediaPipe result frame (the first face)."""
    where = f"frame {k + 1}"
    t = _field(frame, "timestamp_ms", (int, float), where)
    faces = frame.get("face_blendshapes", frame.get("blendshapes"))
    if faces is None:
        raise ShapeSpaceError(f"{where} has no 'face_blendshapes'", ErrorCode.CORRUPT_FILE)
    if not isinstance(faces, list):
        raise ShapeSpaceError(f"{where}: 'face_blendshapes' is a {type(faces).__name__}", ErrorCode.CORRUPT_FILE)
    if faces and isinstance(faces[0], list):           # one list of categories per face: the first face
        faces = faces[0]
    scores = {}
    for c in faces:
        name = c.get("category_name") if isinstance(c, dict) else None
        score = c.get("score") if isinstance(c, dict) else None
        if not isinstance(name, str) or isinstance(score, bool) or not isinstance(score, (int, float)):
            raise ShapeSpaceError(f"{where}: a category without a category_name and a numeric score",
                                  ErrorCode.CORRUPT_FILE)
        if math.isfinite(score) and abs(score) > MAX_ABS_WEIGHT:
            raise ShapeSpaceError(f"{where}, {name}: {score:g} is beyond ±{MAX_ABS_WEIGHT:g}: a damaged value",
                                  ErrorCode.RANGE)
        scores[name] = float(score)
    return float(t), scores


_CATEGORY_NAME, _SCORE = itemgetter("category_name"), itemgetter("score")
_NUMBER_TYPES = {float, int}


def _mediapipe_plain(frame) -> tuple | None:
    """``(timestamp ms, category names, scores)`` of a frame of the usual shape — a dict whose first face lists
    categories with a name and a numeric score — read with C-level built-ins only (the scores' range is checked
    for all frames at once: :meth:`_Rows.check_range`); ``None`` for anything else (:func:`_mediapipe_frame`
    then reads it and names what is wrong)."""
    if type(frame) is not dict:
        return None
    t = frame.get("timestamp_ms")
    faces = frame.get("face_blendshapes", frame.get("blendshapes"))
    if type(t) not in _NUMBER_TYPES or type(faces) is not list or not faces:
        return None
    cats = faces[0] if type(faces[0]) is list else faces
    try:
        names, scores = list(map(_CATEGORY_NAME, cats)), list(map(_SCORE, cats))
    except (KeyError, TypeError):
        return None
    if not scores or not set(map(type, scores)) <= _NUMBER_TYPES:
        return None
    return t, names, scores


class _Rows:
    """Score rows of a MediaPipe recording gathered frame by frame into flat arrays of doubles (one per run of
    frames of the same width: a category first seen later widens the rows), with the categories' columns in
    the order first seen."""

    def __init__(self) -> None:
        self.column, self.names, self.times = {}, [], array_of("d")
        self.runs = [(0, array_of("d"))]               # (width, flat values) per run of frames
        self.known = None                                # the last frame's names, when they were all the columns
        self.lost = 0

    def add_plain(self, ms: float, names: list, scores: list) -> bool:
        """Add a frame read by :func:`_mediapipe_plain` whose names are the columns in order (as a rule every
        frame's); ``False`` (nothing added) otherwise."""
        if names != self.known:
            if names != self.names:
                return False
            self.known = names
        try:
            row = array_of("d", scores)
        except OverflowError:                          # an integer beyond a double: read by the cell reader
            return False
        self.times.append(ms / 1000.0)
        self.runs[-1][1].extend(row)
        return True

    def check_range(self) -> None:
        """Refuse the first score (frame, then category order) beyond ±:data:`MAX_ABS_WEIGHT`, as
        :func:`_mediapipe_frame` does frame by frame."""
        at = 0
        for width, values in self.runs:
            count = len(values) // width if width else 0
            a = np.frombuffer(values, dtype=np.float64)
            bad = np.flatnonzero(np.isfinite(a) & (np.abs(a) > MAX_ABS_WEIGHT))
            if bad.size:
                f, j = divmod(int(bad[0]), width)
                raise ShapeSpaceError(f"frame {at + f + 1}, {self.names[j]}: {a[bad[0]]:g} is beyond "
                                      f"±{MAX_ABS_WEIGHT:g}: a damaged value", ErrorCode.RANGE)
            at += count

    def add(self, ms: float, scores: dict, k: int) -> None:
        """Add a frame read by :func:`_mediapipe_frame` (new categories become new columns)."""
        for name in scores:
            if name not in self.column:
                if len(self.column) >= MAX_CHANNELS:
                    raise ShapeSpaceError(f"frame {k + 1}: more than {MAX_CHANNELS} category names",
                                          ErrorCode.TOO_LARGE)
                self.column[name] = len(self.names)
                self.names.append(name)
                self.known = None
        if len(self.names) != self.runs[-1][0]:
            self.runs.append((len(self.names), array_of("d")))
        row = [math.nan] * len(self.names)
        for name, score in scores.items():
            row[self.column[name]] = score
        self.lost += not scores
        self.times.append(ms / 1000.0)
        self.runs[-1][1].extend(row)

    def matrix(self) -> np.ndarray:
        """The weights (frames, columns), NaN where a frame had no score for a column."""
        w = np.full((len(self.times), len(self.names)), np.nan)
        at = 0
        for width, values in self.runs:
            count = len(values) // width if width else 0
            if count:
                w[at:at + count, :width] = np.frombuffer(values, dtype=np.float64).reshape(count, width)
            at += count
        return w


def _mediapipe_json(source: str | _Text, required: Sequence[str]) -> WeightStream:
    """A MediaPipe JSON recording, one frame at a time: a list of frames is never held as Python objects, nor
    (from a file, :func:`read_capture`) as one text."""
    rows = _Rows()
    template = _FrameTemplate(rows)
    k = 0
    try:
        with _collection_paused():
            for frame in _json_frames(source if isinstance(source, _Text) else _Text(source), template):
                if type(frame) is tuple:               # (count,): frames read by the template (JSON has no tuple)
                    k += frame[0]
                    continue
                plain = _mediapipe_plain(frame)
                if plain is None or not rows.add_plain(*plain):
                    rows.add(*_mediapipe_frame(frame, k), k)
                k += 1
    except ShapeSpaceError:
        rows.check_range()                  # a damaged score of an earlier frame is named first, frame by frame
        raise
    rows.check_range()
    if not rows.names:
        raise ShapeSpaceError("the MediaPipe JSON has no blendshape scores", ErrorCode.NO_CHANNELS)
    cols, kept, issues = _columns(rows.names, required)
    w = rows.matrix()
    rows.runs.clear()
    t = np.frombuffer(rows.times, dtype=np.float64).copy()
    _check_time(t)
    if rows.lost:
        issues.append(Issue("warning", "no_face", f"{rows.lost} frames found no face; filled from the neighbours"))
    return finish_stream(t, w[:, cols], kept, np.arange(1, t.size + 1), issues, None, "mediapipe_json")


_WS = re.compile(r"[ \t\n\r]*")
#: Characters of a MediaPipe JSON recording kept ahead of the frame being parsed (a frame is ~5 K).
_JSON_AHEAD = 1 << 20


@contextmanager
def _collection_paused():
    """The cyclic garbage collector paused (and restored as it was): a recording's ~100 short-lived containers
    per frame would otherwise start a collection every few frames, for nothing (they are freed by reference
    counting) — a fifth of the reading time."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


class _Text:
    """A text read on demand from its pieces (:func:`~.capture.read_capture_chunks`): ``text`` holds the part
    not yet parsed, which starts at ``line``, ``column`` of the whole (for messages)."""

    def __init__(self, text: str, pieces: Iterator[str] | None = None) -> None:
        self.text, self.pieces, self.line, self.column = text, pieces, 1, 1

    def ahead(self, at: int, size: int | None = None) -> int:
        """Make ``text[at:at + size]`` present when the whole has it (the text before ``at`` is dropped);
        returns the new index of ``at`` (``size``: :data:`_JSON_AHEAD` when None)."""
        size = size or _JSON_AHEAD
        if self.pieces is None or len(self.text) - at >= size:
            return at
        breaks = self.text.count("\n", 0, at)
        self.line += breaks
        self.column = at - self.text.rfind("\n", 0, at) if breaks else self.column + at
        parts, have = [self.text[at:]], len(self.text) - at
        while have < size:
            piece = next(self.pieces, None)
            if piece is None:
                self.pieces = None
                break
            parts.append(piece)
            have += len(piece)
        self.text = "".join(parts)
        return 0

    def where(self, at: int) -> tuple:
        """``(line, column)`` in the whole of ``text[at]``."""
        breaks = self.text.count("\n", 0, at)
        return self.line + breaks, (at - self.text.rfind("\n", 0, at) if breaks else self.column + at)

    def skip_space(self, at: int) -> int:
        """The index of the first character from ``at`` that is not JSON white space (reading on as needed)."""
        while True:
            at = _WS.match(self.text, at).end()
            if at < len(self.text) or self.pieces is None:
                return at
            at = self.ahead(at)


#: A JSON number as a template hole reads it: JSON's syntax, at most 16 integer digits (a longer one, or ``-0``
#: — an integer zero to the json module, a negative float to ``float`` — is left to the JSON parser).
_HOLE = r"((?!-0(?![.0-9eE]))-?(?:0|[1-9][0-9]{0,15})(?:\.[0-9]+)?(?:[eE][-+]?[0-9]+)?)"
_SEP = re.compile(r"[ \t\n\r]*,[ \t\n\r]*")
_KEY_BEFORE = re.compile(r'("[A-Za-z_]+")[ \t\n\r]*:[ \t\n\r]*\Z')
#: Most frames a template reads at once, and most frames parsed while learning one.
_TEMPLATE_RUN, _TEMPLATE_TRIES = 256, 16


class _FrameTemplate:
    """MediaPipe frames read without the JSON parser: the text of a frame as a recording's writer repeats it
    (the same keys, categories, indices, spacing and separator), its timestamp and scores left as holes.

    It is learnt from a frame the JSON parser read (:meth:`learn`) and proved on it: the frame's text with
    every hole replaced by a distinct value parses to a frame of the usual shape (:func:`_mediapipe_plain`)
    whose timestamp and scores are exactly those values, with the frame's category names — so any text equal
    to the template with a JSON number in each hole is that frame with those numbers.  :meth:`take` reads a
    run of frames when their text is exactly the template filled with the numbers found after the holes'
    keys (one string comparison: anything else — a lost face, another order, a NaN, damaged text — is left
    to the JSON parser, frame by frame, which names what is wrong).  Numbers become doubles by ``float``, as
    the parser's do.
    """

    def __init__(self, rows: _Rows) -> None:
        self.rows, self.form, self.tries = rows, None, 0
        self.run, self.wait, self.misses = 1, 0, 0

    def learn(self, frame, text: str, start: int, end: int) -> None:
        """Learn the template from ``frame``, parsed from ``text[start:end]`` (a ``,`` and the next frame follow)."""
        if self.form is not None or self.tries >= _TEMPLATE_TRIES:
            return
        self.tries += 1
        sep = _SEP.match(text, end)
        plain = _mediapipe_plain(frame)
        if sep is None or plain is None or plain[1] != self.rows.names or len(set(plain[1])) != len(plain[1]):
            return
        raw = text[start:end]
        holes = [(m.start(), m.end(), m.group(1)) for m in re.finditer(_HOLE, raw)
                 if _key_before(raw, m.start()) in ('"timestamp_ms"', '"score"')]
        if not holes:
            return
        probe = _filled(raw, holes, [f"{k + 1}.5" for k in range(len(holes))])
        try:
            proved = _mediapipe_plain(json.loads(probe))
        except (ValueError, RecursionError):
            return
        if proved is None or proved[1] != plain[1] or len(holes) != len(plain[1]) + 1:
            return
        order = {v: k for k, v in enumerate([proved[0], *proved[2]])}     # hole values: time, then scores
        roles = [order.get(float(f"{k + 1}.5"), -1) - 1 for k in range(len(holes))]
        if sorted(roles) != list(range(-1, len(plain[1]))):
            return
        prefix = {r: raw[_KEY_BEFORE.search(raw, max(0, a - 64), a).start():a] for (a, _, _), r in zip(holes, roles)}
        if len({p for r, p in prefix.items() if r >= 0}) != 1:
            return
        self.roles, self.names = roles, plain[1]
        self.time_prefix = prefix[-1]
        self.time_re = re.compile(re.escape(prefix[-1]) + _HOLE)
        self.score_re = re.compile(re.escape(prefix[0]) + _HOLE)
        self.form = _filled(raw.replace("%", "%%"), _shifted(raw, holes), ["%s"] * len(holes)) + \
            sep.group().replace("%", "%%")
        self.size = len(raw) + len(sep.group())

    def take(self, src: _Text, at: int) -> tuple:
        """``(end, count)``: the run of ``count`` frames from ``src.text[at]`` read into the rows, the text after
        them (and their separators) at ``end``; ``count`` 0 when the next frame is not the template's (``end``:
        where ``at`` now is, the text read on)."""
        if self.form is None or self.wait or self.rows.names != self.names or \
                self.rows.runs[-1][0] != len(self.names):
            self.wait = max(self.wait - 1, 0)
            return at, 0
        self.run = max(1, min(self.run, _JSON_AHEAD * 4 // (5 * self.size) - 2))      # text held: ~_JSON_AHEAD
        at = src.ahead(at, (self.run + 2) * self.size * 5 // 4)
        text, times, starts, pos = src.text, [], [], at
        for _ in range(self.run + 1):                  # each frame's timestamp, and where the next frame's is
            found = text.find(self.time_prefix, pos, pos + 2 * self.size)
            hole = None if found < 0 else self.time_re.match(text, found)
            if hole is None:
                break
            times.append(hole.group(1))
            starts.append(found)
            pos = hole.end()
        count, width = len(times) - 1, len(self.names)
        scores = self.score_re.findall(text, at, starts[-1]) if count > 0 else ()
        if len(scores) < count * width or count < 1:
            return self._missed(at)
        holes = len(self.roles)
        args = [""] * (count * holes)
        for k, role in enumerate(self.roles):
            args[k::holes] = times[:count] if role < 0 else scores[role:count * width:width]
        expected = (self.form * count) % tuple(args)
        if not src.text.startswith(expected, at):
            return self._missed(at)
        t = np.array(times[:count], dtype=np.float64) / 1000.0
        self.rows.times.frombytes(t.tobytes())
        self.rows.runs[-1][1].extend(array_of("d", map(float, scores[:count * width])))
        self.run, self.misses = min(2 * self.run, _TEMPLATE_RUN), 0
        return at + len(expected), count

    def _missed(self, at: int) -> tuple:
        """``(at, 0)``: the next frame is read by the JSON parser; after misses in a row, the next few too."""
        self.misses += self.run == 1
        self.wait = min(2 ** self.misses, 256) if self.run == 1 and self.misses > 1 else 0
        self.run = 1
        return at, 0


def _key_before(raw: str, at: int) -> str | None:
    """The key (its JSON text) of the value at ``raw[at]``, when a plain one (letters and ``_``) is right before
    it."""
    found = _KEY_BEFORE.search(raw, max(0, at - 64), at)
    return found.group(1) if found else None


def _shifted(raw: str, holes: list) -> list:
    """``holes`` (start, end, text) of ``raw`` where they fall in ``raw`` with every ``%`` doubled."""
    return [(a + raw.count("%", 0, a), b + raw.count("%", 0, b), h) for a, b, h in holes]


def _filled(raw: str, holes: list, values: list) -> str:
    """``raw`` with its ``holes`` (start, end, text) replaced by ``values``."""
    parts, at = [], 0
    for (a, b, _), v in zip(holes, values):
        parts += [raw[at:a], v]
        at = b
    return "".join(parts) + raw[at:]


def _json_frames(src: _Text, template: _FrameTemplate | None = None):
    """The frames of a MediaPipe JSON recording one by one: a top-level list streamed element by element
    (``json.JSONDecoder.raw_decode``), or ``{"frames": [...]}`` parsed whole (within :data:`MAX_JSON_BYTES`).
    With a ``template``, runs of frames it reads (:meth:`_FrameTemplate.take`) are yielded as ``(count,)`` (a
    tuple: never a JSON value), and every frame parsed is offered to it to learn from (:meth:`_FrameTemplate.learn`)."""
    at = src.skip_space(src.ahead(0, _SNIFF) + src.text.startswith("\ufeff"))
    if src.text[at:at + 1] != "[":
        data = _json(src.text + "".join(src.pieces or ()))
        frames = data.get("frames") if isinstance(data, dict) else None
        if not isinstance(frames, list):
            raise ShapeSpaceError("the MediaPipe JSON is neither a list of frames nor {\"frames\": [...]}",
                                  ErrorCode.CORRUPT_FILE)
        yield from frames
        return
    decoder = json.JSONDecoder(parse_constant=lambda c: math.nan)
    at = src.skip_space(at + 1)
    if src.text[at:at + 1] == "]":
        at += 1
    else:
        while True:
            if template is not None:
                at, count = template.take(src, at)
                if count:
                    yield (count,)
                    continue
            frame, start, at = _decode_frame(src, decoder, src.ahead(at))
            yield frame
            if template is not None:
                template.learn(frame, src.text, start, at)
            at = src.skip_space(at)
            sep = src.text[at:at + 1]
            at = src.skip_space(at + 1)
            if sep == "]":
                break
            if sep != ",":
                raise ShapeSpaceError(f"line {src.where(at)[0]}: the list of frames is not valid JSON "
                                      "(expected ',' or ']')", ErrorCode.CORRUPT_FILE)
    if src.skip_space(at) != len(src.text):
        raise ShapeSpaceError(f"line {src.where(at)[0]}: text after the list of frames", ErrorCode.CORRUPT_FILE)


def _decode_frame(src: _Text, decoder: json.JSONDecoder, at: int) -> tuple:
    """``(frame, start, end)``: the JSON value at ``src.text[at]`` (read on while it runs past the text read so
    far), which spans ``src.text[start:end]``."""
    size = _JSON_AHEAD
    while True:
        try:
            frame, end = decoder.raw_decode(src.text, at)
            return frame, at, end
        except json.JSONDecodeError as exc:
            if src.pieces is not None and exc.pos >= len(src.text) - size // 2:
                size *= 2                                 # the frame may go on in the next piece
                at = src.ahead(at, size)
                continue
            line, column = src.where(exc.pos)
            raise ShapeSpaceError(f"line {line}, column {column}: not valid JSON ({exc.msg})",
                                  ErrorCode.CORRUPT_FILE) from None
        except (RecursionError, ValueError) as exc:
            raise ShapeSpaceError(f"not readable JSON ({type(exc).__name__})", ErrorCode.CORRUPT_FILE) from None


def _mediapipe_csv(text: str, required: Sequence[str]) -> WeightStream:
    rows = _csv_rows(text)
    first = next(rows, None)
    if first is None:
        raise ShapeSpaceError("the CSV file is empty", ErrorCode.EMPTY)
    header = [h.strip() for h in first[1]]
    if "timestamp_ms" not in header:
        raise ShapeSpaceError("line 1: the CSV has no timestamp_ms column: not a MediaPipe recording",
                              ErrorCode.NO_TIMECODE)
    t_col = header.index("timestamp_ms")
    names = [h for j, h in enumerate(header) if j != t_col]
    cols, kept, issues = _columns(names, required)
    cols = [c + (c >= t_col) for c in cols]                 # back to header columns
    plain = None if '"' in text else plain_rows(text.replace("\r\n", "\n").replace("\r", "\n")
                                                .split("\n", 1)[-1].rstrip() + "\n", len(header))
    if plain is not None and not np.any(np.abs(plain[:, cols]) > MAX_ABS_WEIGHT) and plain[0].size:
        t = plain[:, t_col] / 1000.0
        return finish_stream(t, np.ascontiguousarray(plain[:, cols]), kept, np.arange(2, t.size + 2), issues, None,
                             "mediapipe_csv")
    times, values, lines = array_of("d"), array_of("d"), array_of("q")
    for i, r in rows:
        if len(r) != len(header):
            raise ShapeSpaceError(f"line {i} has {len(r)} cells, the header has {len(header)}", ErrorCode.RAGGED)
        times.append(_number(r[t_col], f"line {i}, column 'timestamp_ms'", 1e12) / 1000.0)
        values.extend([_number(r[j], f"line {i}, column {header[j]!r}", MAX_ABS_WEIGHT) for j in cols])
        lines.append(i)
    t = np.frombuffer(times, dtype=np.float64).copy()
    _check_time(t)
    w = _frames(values, t.size, len(cols))
    return finish_stream(t, w, kept, np.frombuffer(lines, dtype=np.int64).copy(), issues, None, "mediapipe_csv")
