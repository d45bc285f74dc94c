"""Capture sources: Live Link Face CSV recordings and resampling to scene frames (thesis 3.5).

Live Link Face writes one row per captured frame::

    Timecode,BlendShapeCount,EyeBlinkLeft,...,TongueOut,HeadYaw,...,RightEyeRoll
    00:32:09:07.867,61,0.049,...

The timecode is ``HH:MM:SS:FF.fff`` at 60 frames per second (the fractional
part subdivides a frame).  :func:`read_live_link_csv` validates the file and
returns seconds and weights; :func:`resample` interpolates any weight stream
onto scene frames at another rate.

Limits (each refusal is a :class:`~core.result.ShapeSpaceError` naming the file and line):

- only regular files of at most :data:`MAX_FILE_BYTES` are read (a directory,
  FIFO or device is refused before it is opened for reading);
- a take may cross midnight (``23:59:59 → 00:00:00``: the later rows continue
  the day), but hours must be 0–23, consecutive rows at most
  :data:`MAX_GAP_SECONDS` apart and the whole take at most
  :data:`MAX_TAKE_SECONDS` long;
- weights beyond ± :data:`MAX_ABS_WEIGHT` are damaged cells; channels leaving
  ``[0, 1]`` by more than :data:`WEIGHT_SLACK` are reported;
- :func:`resample` refuses to build more than :data:`MAX_RESAMPLE_BYTES`.
"""
from __future__ import annotations

import codecs
import csv
import math
import os
import re
import stat
import warnings
from array import array as array_of
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from ..blendshape import MAX_ABS_WEIGHT
from ..errors import ErrorCode
from ..headpose import ROTATION_CHANNELS as HEAD_EYE_CHANNELS
from ..names import ARKIT_52, canonical_name
from ..result import Issue, ShapeSpaceError
from ..validate import array

__all__ = ["WeightStream", "parse_timecode", "read_live_link_csv", "resample", "finish_stream", "read_capture_text",
           "read_capture_chunks", "capture_path", "plain_rows",
           "ROTATION_CHANNELS", "MAX_FILE_BYTES", "MAX_TAKE_SECONDS", "MAX_GAP_SECONDS", "MAX_ABS_WEIGHT",
           "MAX_RESAMPLE_BYTES"]

#: The head and eye rotation channels of a stream, in :attr:`WeightStream.rotations` column order (radians,
#: the live frames' convention: :class:`core.live.LiveFrame`); the Live Link Face CSV's column names.
ROTATION_CHANNELS = HEAD_EYE_CHANNELS

#: Live Link Face's timecode rate.
LLF_TIMECODE_FPS = 60.0

#: Largest capture file read, in bytes (a Live Link Face take is ~0.6 KB a frame: ~2 h at 60 fps).
MAX_FILE_BYTES = 256 * 2 ** 20

#: Longest take accepted, in seconds.
MAX_TAKE_SECONDS = 4 * 3600.0

#: Longest jump between consecutive timecodes, in seconds: a longer one is a damaged row, not a pause.
MAX_GAP_SECONDS = 60.0

#: Seconds in a day: a timecode more than half a day before the previous row is on the next day.
DAY_SECONDS = 86400.0

#: Channels whose weights leave ``[-WEIGHT_SLACK, 1 + WEIGHT_SLACK]`` are reported (a warning).
WEIGHT_SLACK = 0.1

#: Largest resampled stream, in bytes of float64 weights (frames × channels × 8).
MAX_RESAMPLE_BYTES = 2 ** 30


@dataclass
class WeightStream:
    """Slider weights sampled over time.

    Attributes
    ----------
    names : list of str
        Channel names as in the source.
    times : ndarray (f,)
        Strictly increasing sample times in seconds, starting at 0.
    weights : ndarray (f, n)
    issues : list of Issue
        What was repaired or noticed while reading (NaN filled, gaps, …).
    start_timecode : str
        The source's time of the first sample as it wrote it ('' when it has none).
    rotations : ndarray (f, 9) or None
        Head, left-eye and right-eye ``(yaw, pitch, roll)`` in radians (:data:`ROTATION_CHANNELS`, the live
        frames' face-frame convention), when the source records them.
    kind : str
        The source format (``llf_csv``, ``facecap_txt``, …; :mod:`.formats`).
    rate : float or None
        The source's nominal sample rate in frames per second, when it states one.
    """

    names: list
    times: np.ndarray
    weights: np.ndarray
    issues: list = field(default_factory=list)
    start_timecode: str = ""
    rotations: np.ndarray | None = None
    kind: str = "llf_csv"
    rate: float | None = None


def parse_timecode(text: str, fps: float = LLF_TIMECODE_FPS) -> float:
    """``HH:MM:SS:FF(.fff)`` → seconds of the day (hours 0–23; a take crossing midnight is unwrapped by
    :func:`read_live_link_csv`)."""
    parts = text.strip().split(":")
    if len(parts) != 4:
        raise ShapeSpaceError(f"timecode {text!r} is not HH:MM:SS:FF", "timecode")
    try:
        h, m, s = int(parts[0]), int(parts[1]), int(parts[2])
        frames = float(parts[3])
    except ValueError:
        raise ShapeSpaceError(f"timecode {text!r} is not HH:MM:SS:FF", "timecode") from None
    if not (0 <= h < 24 and 0 <= m < 60 and 0 <= s < 60 and 0 <= frames < fps):
        raise ShapeSpaceError(f"timecode {text!r} is out of range (HH 0–23, MM and SS 0–59, FF below {fps:g})",
                              ErrorCode.TIMECODE)
    return h * 3600.0 + m * 60.0 + s + frames / fps


def read_live_link_csv(source: str | os.PathLike, required: Sequence[str] = ARKIT_52,
                       fps: float = LLF_TIMECODE_FPS, rotations: bool = False) -> WeightStream:
    """Read a Live Link Face CSV (path or text) into a :class:`WeightStream`.

    Validation (each a clear error naming the file and line, or a recorded issue):

    - not a regular file, larger than :data:`MAX_FILE_BYTES`, not UTF-8 or
      not parseable as CSV (stray quote, a cell beyond the csv module's limit)
      → error;
    - missing ``Timecode`` column or no ARKit channel at all → error;
    - missing, extra or renamed channels → the ARKit channels present are
      kept (matched by canonical name), the rest listed in ``issues``;
    - NaN / empty cells → linearly filled from the neighbouring frames
      (issue), or error if a channel has no valid value; a weight beyond
      ±:data:`MAX_ABS_WEIGHT` → error; channels leaving ``[0, 1]`` → issue;
    - a take crossing midnight → later rows continue the day (issue);
      impossible timecodes (hour ≥ 24, …) → error; timecode gaps
      (> 2.5 frame periods) → issue, beyond :data:`MAX_GAP_SECONDS` → error;
      a take longer than :data:`MAX_TAKE_SECONDS` → error; reversed or
      repeated timecodes → rows sorted, duplicates dropped (issue);
    - fewer than 3 frames → error (nothing to retarget).

    Parameters
    ----------
    source : str or os.PathLike
        A file path, or the CSV text itself (a ``str`` with a line break that names no file).
    required : sequence of str
        The channels wanted (matched by canonical name).
    fps : float
        Timecode frame rate.
    rotations : bool
        Also read the head and eye columns (:data:`ROTATION_CHANNELS`, all nine present) into
        ``rotations``; they are then not listed as ignored columns.

    Returns
    -------
    WeightStream
        ``times`` (f,) from 0, ``weights`` (f, n) for the n channels found, all finite.

    Raises
    ------
    ShapeSpaceError
        Every failure (never another exception); from a file, the message starts with its path.
    """
    text, label = read_capture_text(source)
    try:
        return _parse(text, required, fps, rotations)
    except ShapeSpaceError as exc:
        if label is None:
            raise
        raise ShapeSpaceError(f"{label}: {exc}", exc.code) from None


def _parse(text: str, required: Sequence[str], fps: float, rotations: bool = False) -> WeightStream:
    """The stream of a CSV text (errors name the line, not the file)."""
    numbered = _csv_rows(text)                   # streamed: a long take is never held as rows of strings
    first = next(numbered, None)
    if first is None:
        raise ShapeSpaceError("the CSV file is empty", ErrorCode.EMPTY)
    header = [h.strip() for h in first[1]]
    if "Timecode" not in header:
        raise ShapeSpaceError("the CSV has no Timecode column: not a Live Link Face recording",
                              ErrorCode.NO_TIMECODE)
    t_col = header.index("Timecode")
    rot_cols = [header.index(c) for c in ROTATION_CHANNELS] if rotations and set(ROTATION_CHANNELS) <= set(header) \
        else []
    cols, names, issues = _channel_columns(header, t_col, required, rot_cols)
    fast = _plain_llf_rows(text, header, t_col, cols + rot_cols, fps)
    t, w, lines, stamps = fast or _read_rows(numbered, header, t_col, cols + rot_cols, fps)
    t = _unwrap_midnight(t, lines, issues)
    rot = w[:, len(cols):] if rot_cols else None
    stream = finish_stream(t, w[:, :len(cols)], names, lines, issues, rot)
    stream.start_timecode = stamps[int(np.argmin(t))].strip()
    stream.rate = fps
    return stream


_PLAIN = re.compile(r"[0-9eE.+\-,\n naifNAIF]*")


_PLAIN_COLONS = re.compile(r"[0-9eE.+\-,:\n naifNAIF]*")
#: Characters of text parsed at a time by :func:`plain_rows` (bounds its temporaries, whatever the file size).
PLAIN_CHUNK = 1 << 22


def plain_rows(body: str, width: int, start: int = 0, stop: int | None = None,
               colons: bool = False) -> np.ndarray | None:
    """The numbers of ``body[start:stop]`` as (rows, width), read in one C pass per chunk of
    :data:`PLAIN_CHUNK` characters, when it is lines (none blank) of exactly ``width`` comma-separated plain
    numbers (``colons``: ``:`` separates too, as in a timecode); ``None`` otherwise (an empty or damaged cell,
    a ragged line, other syntax): the caller's per-cell reader then reads it and names the culprit.  The text
    is never copied whole: a long take is parsed in bounded memory."""
    stop = len(body) if stop is None else stop
    pattern = _PLAIN_COLONS if colons else _PLAIN
    if start >= stop or body.find("\n\n", start, stop) >= 0 or not pattern.fullmatch(body, start, stop):
        return None
    rows = []
    while start < stop:
        end = body.rfind("\n", start, min(stop, start + PLAIN_CHUNK)) + 1
        if end <= start:
            end = body.find("\n", start, stop) + 1 or stop
        part = body[start:end] if body[end - 1] == "\n" else body[start:end] + "\n"
        a = _plain_chunk(part.replace(":", ",") if colons else part, width)
        if a is None:
            return None
        rows.append(a)
        start = end
    return rows[0] if len(rows) == 1 else np.concatenate(rows)


def _plain_chunk(body: str, width: int) -> np.ndarray | None:
    """:func:`plain_rows` of whole lines (``body`` ends in a newline)."""
    raw = np.frombuffer(body.encode("ascii"), dtype=np.uint8)
    ends = np.flatnonzero(raw == 10)
    commas = np.bincount(np.searchsorted(ends, np.flatnonzero(raw == 44)), minlength=ends.size)
    del raw
    if np.any(commas != width - 1) or np.max(np.diff(ends, prepend=-1)) > csv.field_size_limit():
        return None                                       # ragged, or a cell the csv module refuses
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            values = np.fromstring(body.replace("\n", ","), sep=",")
        except (DeprecationWarning, ValueError):
            return None
    if values.size != ends.size * width or not np.isfinite(values).all():
        return None                                       # NaN / infinite cells: read (and filled) per cell
    return values.reshape(ends.size, width)


class _FirstFields:
    """The first cell of each line of a body of text from ``start``, looked up on demand (a long take's
    timecodes are never held as strings)."""

    def __init__(self, body: str, start: int = 0) -> None:
        self.body, self.start = body, start

    def __getitem__(self, k: int) -> str:
        at = self.start
        for _ in range(k):
            at = self.body.index("\n", at) + 1
        end = self.body.find("\n", at)
        return self.body[at:end if end >= 0 else len(self.body)].split(",", 1)[0]


def _plain_llf_rows(text: str, header: list, t_col: int, cols: list, fps: float) -> tuple | None:
    """:func:`_read_rows`'s result from a take of plain rows (no quotes, timecode first, every cell a number,
    every timecode in range) in one pass (:func:`plain_rows`); ``None`` for anything else (the per-row
    reader then reads it and names what is wrong)."""
    if t_col != 0 or '"' in text:
        return None
    if "\r" in text:
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    nl = text.find("\n")
    if nl < 0 or [h.strip() for h in text[:nl].split(",")] != header:
        return None
    stop = len(text)
    while stop > nl + 1 and text[stop - 1] == "\n":
        stop -= 1
    a = plain_rows(text, len(header) + 3, nl + 1, stop, colons=True)
    if a is None or a.shape[0] == 0:
        return None
    h, m, s, ff = a[:, 0], a[:, 1], a[:, 2], a[:, 3]
    whole = np.all((h == np.floor(h)) & (m == np.floor(m)) & (s == np.floor(s)))
    if not (whole and np.all((h >= 0) & (h < 24) & (m >= 0) & (m < 60) & (s >= 0) & (s < 60) & (ff >= 0)
                             & (ff < fps))):
        return None
    w = a[:, [j + 3 for j in cols]]
    if np.any(np.isfinite(w) & (np.abs(w) > MAX_ABS_WEIGHT)):
        return None
    t = h * 3600.0 + m * 60.0 + s + ff / fps
    return t, np.ascontiguousarray(w), np.arange(2, t.size + 2, dtype=np.int64), _FirstFields(text, nl + 1)


def finish_stream(t: np.ndarray, w: np.ndarray, names: list, lines: np.ndarray, issues: list,
                  rotations: np.ndarray | None = None, kind: str = "llf_csv") -> WeightStream:
    """The checks every capture reader shares, on samples in file order: rows sorted by time (issue),
    repeated times dropped (issue), at least 3 frames, no gap beyond :data:`MAX_GAP_SECONDS`, a take of
    at most :data:`MAX_TAKE_SECONDS`, NaN cells filled from the neighbours (issue; a channel with no value
    is refused), weights leaving ``[0, 1]`` and time gaps reported.

    Parameters
    ----------
    t : ndarray (f,)
        Sample times in seconds (any origin), file order.
    w : ndarray (f, n)
        Weights (NaN for a missing cell).
    names : list of str
        The n channel names.
    lines : ndarray (f,)
        Each sample's line (or record) number, for messages.
    issues : list of Issue
        What the reader noticed so far (extended in place).
    rotations : ndarray (f, 9) or None
        Head and eye ``(yaw, pitch, roll)`` radians (NaN for a missing cell).
    kind : str
        The source format.

    Returns
    -------
    WeightStream
        Times from 0, strictly increasing; every value finite.
    """
    both = w if rotations is None else np.concatenate([w, rotations], axis=1)
    order = np.argsort(t, kind="stable")
    if np.any(np.diff(t) < 0):
        issues.append(Issue("warning", "reversed_timecode", "timecodes were out of order; rows were sorted"))
    t, both, lines = t[order], both[order], lines[order]
    keep = np.concatenate([[True], np.diff(t) > 1e-9])
    if not keep.all():
        issues.append(Issue("warning", "repeated_timecode", f"dropped {int((~keep).sum())} rows with a repeated "
                            "timecode"))
        t, both, lines = t[keep], both[keep], lines[keep]
    if t.size < 3:
        raise ShapeSpaceError(f"the recording has {t.size} frames; at least 3 are needed", ErrorCode.TOO_SHORT)
    _check_span(t, lines)
    n = w.shape[1]
    all_names = list(names) + (list(ROTATION_CHANNELS) if rotations is not None else [])
    issues += _fill_and_check(t, both, all_names, lines, n)
    rot = None if rotations is None else np.ascontiguousarray(both[:, n:])
    return WeightStream(list(names), t - t[0], np.ascontiguousarray(both[:, :n]), issues, "", rot, kind)


def _csv_rows(text: str) -> Iterator[tuple]:
    """``(line, cells)`` of each non-blank record, one at a time; any line ending (LF, CRLF, CR) ends a line."""
    if "\r" in text:
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    reader = csv.reader(_lines(text))
    while True:
        start = reader.line_num + 1         # the record's first line (a quoted cell may span lines)
        try:
            row = next(reader)
        except StopIteration:
            return
        except csv.Error as exc:
            raise ShapeSpaceError(f"line {start}: not a readable CSV row ({exc}; a stray quote?)",
                                  ErrorCode.CORRUPT_FILE) from None
        if any(c.strip() for c in row):
            yield reader.line_num, row


def _channel_columns(header: list, t_col: int, required: Sequence[str], used: Sequence[int] = ()) -> tuple:
    """Columns of the wanted channels (first match per canonical name), their names, and the issues of
    missing and extra columns (``used``: other columns read, not extra)."""
    wanted = {canonical_name(n): n for n in required}
    cols, names, issues = [], [], []
    seen = set()
    for j, h in enumerate(header):
        if j == t_col or h == "BlendShapeCount":
            continue
        canon = canonical_name(h)
        if canon in wanted and canon not in seen:
            cols.append(j)
            names.append(h)
            seen.add(canon)
    if not cols:
        raise ShapeSpaceError("the recording has no ARKit blendshape columns", "no_channels")
    missing = [n for c, n in wanted.items() if c not in {canonical_name(x) for x in names}]
    if missing:
        issues.append(Issue("warning", "missing_channels",
                            f"{len(missing)} ARKit channels are missing from the recording: {', '.join(missing[:6])}"
                            + (" …" if len(missing) > 6 else ""), tuple(missing)))
    extra = [h for j, h in enumerate(header) if j != t_col and h != "BlendShapeCount" and j not in cols
             and j not in used]
    if extra:
        issues.append(Issue("info", "extra_columns", f"ignored {len(extra)} non-blendshape columns "
                            f"({', '.join(extra[:4])}{' …' if len(extra) > 4 else ''})", tuple(extra)))
    return cols, names, issues


def _lines(text: str) -> Iterator[str]:
    """The lines of ``text`` with their ``\n`` (for the csv reader: no copy of the whole text)."""
    start, end = 0, len(text)
    while start < end:
        stop = text.find("\n", start)
        stop = end if stop < 0 else stop + 1
        yield text[start:stop]
        start = stop


def _read_rows(rows: Iterator[tuple], header: list, t_col: int, cols: list, fps: float) -> tuple:
    """Seconds (f,), values (f, n), line numbers (f,) and timecode texts of the data rows ``(line, cells)``, in
    file order (empty cells → NaN); the values go straight into a flat array of doubles (8 bytes each)."""
    times, lines, stamps, values = array_of("d"), array_of("q"), [], array_of("d")
    for i, r in rows:
        if len(r) < len(header):
            raise ShapeSpaceError(f"line {i} has {len(r)} cells, the header has {len(header)}", ErrorCode.RAGGED)
        try:
            times.append(parse_timecode(r[t_col], fps))
        except ShapeSpaceError as exc:
            raise ShapeSpaceError(f"line {i}: {exc}", exc.code) from None
        values.extend([_cell(r[j], i, header[j]) for j in cols])
        lines.append(i)
        stamps.append(r[t_col])
    t = np.frombuffer(times, dtype=np.float64).copy()
    return (t, np.frombuffer(values, dtype=np.float64).copy().reshape(t.size, len(cols)),
            np.frombuffer(lines, dtype=np.int64).copy(), stamps)


def _cell(text: str, line: int, column: str) -> float:
    """One weight cell: a float, NaN when empty; damaged cells refused naming the line and column."""
    cell = text.strip()
    if not cell:
        return np.nan
    try:
        value = float(cell)
    except ValueError:
        raise ShapeSpaceError(f"line {line}, column {column!r}: {cell[:40]!r} is not a number",
                              ErrorCode.NOT_NUMBER) from None
    if math.isfinite(value) and abs(value) > MAX_ABS_WEIGHT:
        raise ShapeSpaceError(f"line {line}, column {column!r}: {cell[:40]} is not a blendshape weight (they lie "
                              f"in [0, 1]; beyond ±{MAX_ABS_WEIGHT:g} a cell is damaged)", ErrorCode.RANGE)
    return value


def _unwrap_midnight(t: np.ndarray, lines: np.ndarray, issues: list) -> np.ndarray:
    """Seconds made monotonic across midnight: a row more than half a day before the previous one (file
    order) is on the next day."""
    wraps = np.diff(t) < -DAY_SECONDS / 2
    if not wraps.any():
        return t
    first = int(lines[1 + int(np.flatnonzero(wraps)[0])])
    issues.append(Issue("info", "midnight", f"the take crosses midnight at line {first}; later timecodes "
                        "continue the day"))
    return t + DAY_SECONDS * np.concatenate([[0], np.cumsum(wraps)])


def _check_span(t: np.ndarray, lines: np.ndarray) -> None:
    """Refuse a jump between consecutive (sorted) timecodes beyond :data:`MAX_GAP_SECONDS`, and a take
    beyond :data:`MAX_TAKE_SECONDS`."""
    steps = np.diff(t)
    k = int(np.argmax(steps))
    if steps[k] > MAX_GAP_SECONDS:
        raise ShapeSpaceError(f"the timecode jumps {_duration(steps[k])} between line {lines[k]} and line "
                              f"{lines[k + 1]} (in time order); a take has no gap longer than "
                              f"{MAX_GAP_SECONDS:g} s: a damaged timecode?", ErrorCode.TIMECODE)
    if t[-1] - t[0] > MAX_TAKE_SECONDS:
        raise ShapeSpaceError(f"the take lasts {_duration(t[-1] - t[0])}; takes longer than "
                              f"{_duration(MAX_TAKE_SECONDS)} are refused (split it)", ErrorCode.TOO_LARGE)


def _duration(seconds: float) -> str:
    return f"{seconds / 3600:.1f} h" if seconds >= 3600 else f"{seconds:.1f} s"


def _fill_and_check(t: np.ndarray, w: np.ndarray, names: list, lines: np.ndarray, n_weights: int = None) -> list:
    """Fill NaN cells in ``w`` (in place) from the neighbouring frames; issues for the fills, channels
    leaving ``[0, 1]`` (the first ``n_weights`` columns: the others are angles) and timecode gaps."""
    issues = []
    n_weights = w.shape[1] if n_weights is None else n_weights
    bad = ~np.isfinite(w)
    if bad.any():
        silent = np.flatnonzero(bad[:, n_weights:].all(axis=0)) + n_weights
        if silent.size:                      # a head / eye angle never recorded: the pose at rest
            w[:, silent] = 0.0
            bad[:, silent] = False
            issues.append(Issue("warning", "rotations_missing", f"{', '.join(names[j] for j in silent)} "
                                "recorded no value: left at rest", tuple(names[j] for j in silent)))
        empty = np.flatnonzero(bad[:, :n_weights].all(axis=0))
        if empty.size:                       # nothing recorded for a weight channel: refuse, naming them all
            listed = ", ".join(repr(names[j]) for j in empty[:4]) + (" …" if empty.size > 4 else "")
            recorded = n_weights - empty.size
            raise ShapeSpaceError(
                f"{'channel' if empty.size == 1 else f'{empty.size} of {n_weights} channels'} {listed} "
                f"{'has' if empty.size == 1 else 'have'} no valid value in {w.shape[0]} rows (NaN or empty)"
                + (f"; only {recorded} channel{'s' if recorded != 1 else ''} recorded: did the capture lose "
                   "tracking?" if recorded < empty.size else ""), ErrorCode.NON_FINITE)
        for j in np.flatnonzero(bad.any(axis=0)):
            ok = ~bad[:, j]
            w[~ok, j] = np.interp(t[~ok], t[ok], w[ok, j])
        if bad.any():
            issues.append(Issue("warning", "filled_nan", f"filled {int(bad.sum())} missing or NaN values from "
                                "neighbouring frames"))
    ww = w[:, :n_weights]
    outside = np.flatnonzero(((ww < -WEIGHT_SLACK) | (ww > 1.0 + WEIGHT_SLACK)).any(axis=0))
    if outside.size:
        listed = ", ".join(f"{names[j]} ({w[:, j].min():.3g} … {w[:, j].max():.3g})" for j in outside[:6])
        issues.append(Issue("warning", "weights_out_of_range",
                            f"{outside.size} channels leave the weight range [0, 1]: {listed}"
                            + (" …" if outside.size > 6 else ""), tuple(names[j] for j in outside)))
    step = np.median(np.diff(t))
    gaps = np.flatnonzero(np.diff(t) > 2.5 * step)
    if gaps.size:
        k = int(gaps[np.argmax(np.diff(t)[gaps])])
        issues.append(Issue("warning", "timecode_gap", f"{gaps.size} gaps in the timecode (largest "
                            f"{np.diff(t).max():.3f} s, before line {lines[k + 1]}); values are interpolated "
                            "across them"))
    return issues


def read_capture_text(source: str | os.PathLike) -> tuple:
    """``(text, label)``: a capture file's text, and the path it came from (``None`` when ``source`` is the text).

    A path must be a regular file of at most :data:`MAX_FILE_BYTES`; it is opened without blocking (a FIFO
    never blocks the reader) and checked with ``fstat`` before a byte is read.
    """
    path = capture_path(source)
    if path is None:
        text = os.fspath(source)
        return (os.fsdecode(text) if isinstance(text, bytes) else text), None
    return _read_file(path), path


def _exists(path: str) -> bool:
    try:
        return os.path.lexists(path)
    except (OSError, ValueError):
        return False


def _open_regular(path: str) -> tuple:
    """``(fd, size)`` of ``path`` opened without blocking, checked with ``fstat`` before a byte is read: a regular
    file of at most :data:`MAX_FILE_BYTES` (the caller closes ``fd``)."""
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0)
    try:
        fd = os.open(path, flags)
    except FileNotFoundError:
        raise ShapeSpaceError(f"file not found: {path}", ErrorCode.MISSING_FILE) from None
    except IsADirectoryError:
        raise ShapeSpaceError(f"{path}: is a directory, not a CSV file", ErrorCode.NOT_A_FILE) from None
    except (OSError, ValueError) as exc:
        raise ShapeSpaceError(f"{path}: cannot be read ({getattr(exc, 'strerror', None) or exc})",
                              ErrorCode.CORRUPT_FILE) from None
    try:
        info = os.fstat(fd)
        if stat.S_ISDIR(info.st_mode):
            raise ShapeSpaceError(f"{path}: is a directory, not a CSV file", ErrorCode.NOT_A_FILE)
        if not stat.S_ISREG(info.st_mode):
            raise ShapeSpaceError(f"{path}: is not a regular file (a FIFO, socket or device); give a CSV file",
                                  ErrorCode.NOT_A_FILE)
        if info.st_size > MAX_FILE_BYTES:
            raise ShapeSpaceError(f"{path}: is {info.st_size / 2 ** 20:.0f} MiB; capture files larger than "
                                  f"{MAX_FILE_BYTES / 2 ** 20:.0f} MiB are refused (split the take)",
                                  ErrorCode.TOO_LARGE)
    except BaseException:
        os.close(fd)
        raise
    return fd, info.st_size


def _too_large(path: str) -> ShapeSpaceError:
    return ShapeSpaceError(f"{path}: is larger than {MAX_FILE_BYTES / 2 ** 20:.0f} MiB; split the take",
                           ErrorCode.TOO_LARGE)


def _not_utf8(path: str, line: int, byte: int) -> ShapeSpaceError:
    return ShapeSpaceError(f"{path}: line {line}: not UTF-8 text (byte {byte}): not a Live Link Face CSV",
                           ErrorCode.CORRUPT_FILE)


def _read_file(path: str) -> str:
    fd, size = _open_regular(path)
    try:
        try:
            with os.fdopen(os.dup(fd), "rb") as fh:
                data = fh.read(size + 1)                  # not a MAX_FILE_BYTES buffer for every read
                if len(data) > size:                      # it grew since fstat
                    data += fh.read(MAX_FILE_BYTES + 1 - len(data))
        except OSError as exc:
            raise ShapeSpaceError(f"{path}: cannot be read ({exc.strerror or exc})", ErrorCode.CORRUPT_FILE) \
                from None
    finally:
        os.close(fd)
    if len(data) > MAX_FILE_BYTES:
        raise _too_large(path)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise _not_utf8(path, data[:exc.start].count(b"\n") + 1, exc.start) from None


def capture_path(source: str | os.PathLike) -> str | None:
    """The path ``source`` names, or ``None`` when it is the text itself (:func:`read_capture_text`'s rule)."""
    if isinstance(source, os.PathLike):
        source = os.fspath(source)
    if isinstance(source, bytes):
        source = os.fsdecode(source)
    if not isinstance(source, str):
        raise ShapeSpaceError(f"a CSV source must be a path or text, got {type(source).__name__}", ErrorCode.TYPE)
    if ("\n" in source or "\r" in source) and not _exists(source):
        return None
    return source


def read_capture_chunks(path: str, size: int | None = None) -> Iterator[str]:
    """The text of the capture file at ``path`` in pieces decoded from ``size`` bytes at a time
    (:data:`PLAIN_CHUNK` when None): a long take is never held whole, nor as bytes and text at once.  The
    checks and messages of :func:`read_capture_text`: a regular file (checked before a byte is read), at most
    :data:`MAX_FILE_BYTES`, UTF-8 (the line and byte of the first bad one)."""
    size = size or PLAIN_CHUNK
    fd, _ = _open_regular(path)
    decoder = codecs.getincrementaldecoder("utf-8-sig")()
    done, lines = 0, 0                               # bytes and line breaks before the current piece
    try:
        with os.fdopen(os.dup(fd), "rb") as fh:
            while True:
                try:
                    data = fh.read(size)
                except OSError as exc:
                    raise ShapeSpaceError(f"{path}: cannot be read ({exc.strerror or exc})",
                                          ErrorCode.CORRUPT_FILE) from None
                if done + len(data) > MAX_FILE_BYTES:
                    raise _too_large(path)
                pending = decoder.getstate()[0]
                try:
                    text = decoder.decode(data, final=not data)
                except UnicodeDecodeError as exc:
                    joined = pending + data
                    at = done - len(pending) + exc.start
                    raise _not_utf8(path, lines + joined[:exc.start].count(b"\n") + 1, at) from None
                done += len(data)
                lines += data.count(b"\n")
                if text:
                    yield text
                if not data:
                    return
    finally:
        os.close(fd)


def resample(times: ArrayLike, weights: ArrayLike, fps: float, start_frame: float = 1.0,
             fps_base: float = 1.0) -> tuple:
    """Resample a stream onto scene frames ``start_frame, start_frame + 1, …`` at ``fps / fps_base``.

    Linear interpolation in time; the last frame is the last one inside the
    recording.  A result larger than :data:`MAX_RESAMPLE_BYTES` is refused
    before anything is allocated.

    Parameters
    ----------
    times : ndarray (f,)
        Strictly increasing, finite sample times in seconds.
    weights : ndarray (f, n)
        Finite.
    fps, fps_base : float
        Scene rate ``fps / fps_base`` frames per second (positive, finite).
    start_frame : float
        Scene frame of the first sample.

    Returns
    -------
    frames : ndarray (g,)
    weights : ndarray (g, n)
    """
    for value in (fps, fps_base):
        if not isinstance(value, (int, float, np.integer, np.floating)) or not (math.isfinite(value) and value > 0):
            raise ShapeSpaceError(f"fps must be positive, got {fps}/{fps_base}", ErrorCode.FPS)
    t = array(times, "times", ndim=1)
    w = array(weights, "weights", shape=(t.size, None))
    if t.size == 0:
        raise ShapeSpaceError("the stream has no samples", ErrorCode.EMPTY)
    if np.any(np.diff(t) <= 0):
        raise ShapeSpaceError("times must be strictly increasing", ErrorCode.UNSORTED)
    start = float(array(start_frame, "start_frame", ndim=0))
    rate = float(fps) / float(fps_base)
    span = float(t[-1]) - float(t[0])
    frames_float = span * rate + 1.0                      # Python floats: overflow is inf, never a warning
    size = frames_float * max(w.shape[1], 1) * 8
    if not (math.isfinite(rate) and math.isfinite(size)) or size > MAX_RESAMPLE_BYTES:
        raise ShapeSpaceError(f"resampling {_duration(span)} at {rate:g} fps makes {frames_float:.3g} frames "
                              f"({size / 2 ** 30:.3g} GiB); the limit is {MAX_RESAMPLE_BYTES / 2 ** 30:g} GiB: "
                              "check the timecodes or split the take", ErrorCode.TOO_LARGE)
    count = math.floor(span * rate + 1e-9) + 1
    sample_t = t[0] + np.arange(count) / rate
    out = np.empty((count, w.shape[1]))
    for j in range(w.shape[1]):
        out[:, j] = np.interp(sample_t, t, w[:, j])
    return start + np.arange(count, dtype=np.float64), out
