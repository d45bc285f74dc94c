"""Capture sources: Live Link Face CSV recordings and resampling to scene frames (thesis 3.5).

Live Link Face writes one row per captured frame::

    Timecode,BlendShapeCount,EyeBlinkLeft,...,TongueOut,HeadYaw,...,RightEyeRoll
    00:32:09:07.867,61,0.049,...

The timecode is ``HH:MM:SS:FF.fff`` at 60 frames per second (the fractional
part subdivides a frame).  :func:`read_live_link_csv` validates the file and
returns seconds and weights; :func:`resample` interpolates any weight stream
onto scene frames at another rate.
"""
from __future__ import annotations

import csv
import io
from dataclasses import dataclass, field

import os
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from ..names import ARKIT_52, canonical_name
from ..result import Issue, ShapeSpaceError

__all__ = ["WeightStream", "parse_timecode", "read_live_link_csv", "resample"]

#: Live Link Face's timecode rate.
LLF_TIMECODE_FPS = 60.0


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
    """

    names: list
    times: np.ndarray
    weights: np.ndarray
    issues: list = field(default_factory=list)
    start_timecode: str = ""


def parse_timecode(text: str, fps: float = LLF_TIMECODE_FPS) -> float:
    """``HH:MM:SS:FF(.fff)`` → seconds."""
    parts = text.strip().split(":")
    if len(parts) != 4:
        raise ShapeSpaceError(f"timecode {text!r} is not HH:MM:SS:FF", "timecode")
    try:
        h, m, s = int(parts[0]), int(parts[1]), int(parts[2])
        frames = float(parts[3])
    except ValueError:
        raise ShapeSpaceError(f"timecode {text!r} is not HH:MM:SS:FF", "timecode") from None
    if not (h >= 0 and 0 <= m < 60 and 0 <= s < 60 and 0 <= frames < fps):
        raise ShapeSpaceError(f"timecode {text!r} is out of range", "timecode")
    return h * 3600.0 + m * 60.0 + s + frames / fps


def read_live_link_csv(source: str | os.PathLike, required: Sequence[str] = ARKIT_52,
                       fps: float = LLF_TIMECODE_FPS) -> WeightStream:
    """Read a Live Link Face CSV (path or text) into a :class:`WeightStream`.

    Validation (each a clear error or a recorded issue):

    - missing ``Timecode`` column or no ARKit channel at all → error;
    - missing, extra or renamed channels → the ARKit channels present are
      kept (matched by canonical name), the rest listed in ``issues``;
    - NaN / empty cells → linearly filled from the neighbouring frames
      (issue), or error if a channel has no valid value;
    - timecode gaps (> 2.5 frame periods) → issue; reversed or repeated
      timecodes → rows sorted, duplicates dropped (issue);
    - fewer than 3 frames → error (nothing to retarget).

    Parameters
    ----------
    source : str or os.PathLike
        A file path, or the CSV text itself.
    required : sequence of str
        The channels wanted (matched by canonical name).
    fps : float
        Timecode frame rate.

    Returns
    -------
    WeightStream
        ``times`` (f,) from 0, ``weights`` (f, n) for the n channels found.
    """
    text = _read_text(source)
    numbered = [(i, r) for i, r in enumerate(csv.reader(io.StringIO(text)), start=1) if any(c.strip() for c in r)]
    rows = [r for _, r in numbered]
    line_of = [i for i, _ in numbered]
    if not rows:
        raise ShapeSpaceError("the CSV file is empty", "empty")
    header = [h.strip() for h in rows[0]]
    if "Timecode" not in header:
        raise ShapeSpaceError("the CSV has no Timecode column: not a Live Link Face recording", "no_timecode")
    t_col = header.index("Timecode")
    cols, names, issues = _channel_columns(header, t_col, required)
    t, w = _read_rows(rows, line_of, header, t_col, cols, fps)
    order = np.argsort(t, kind="stable")
    if np.any(np.diff(t) < 0):
        issues.append(Issue("warning", "reversed_timecode", "timecodes were out of order; rows were sorted"))
    t, w = t[order], w[order]
    keep = np.concatenate([[True], np.diff(t) > 1e-9])
    if not keep.all():
        issues.append(Issue("warning", "repeated_timecode", f"dropped {int((~keep).sum())} rows with a repeated "
                            "timecode"))
        t, w = t[keep], w[keep]
    if t.size < 3:
        raise ShapeSpaceError(f"the recording has {t.size} frames; at least 3 are needed", "too_short")
    issues += _fill_and_check(t, w, names)
    start = rows[1 + int(order[0])][t_col] if len(rows) > 1 else ""
    return WeightStream(names, t - t[0], w, issues, start)


def _channel_columns(header: list, t_col: int, required: Sequence[str]) -> tuple:
    """Columns of the wanted channels (first match per canonical name), their names, and the issues of
    missing and extra columns."""
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
        raise ShapeSpaceError("the CSV has no ARKit blendshape columns", "no_channels")
    missing = [n for c, n in wanted.items() if c not in {canonical_name(x) for x in names}]
    if missing:
        issues.append(Issue("warning", "missing_channels",
                            f"{len(missing)} ARKit channels are missing from the CSV: {', '.join(missing[:6])}"
                            + (" …" if len(missing) > 6 else ""), tuple(missing)))
    extra = [h for j, h in enumerate(header) if j != t_col and h != "BlendShapeCount" and j not in cols]
    if extra:
        issues.append(Issue("info", "extra_columns", f"ignored {len(extra)} non-blendshape columns "
                            f"({', '.join(extra[:4])}{' …' if len(extra) > 4 else ''})", tuple(extra)))
    return cols, names, issues


def _read_rows(rows: list, line_of: list, header: list, t_col: int, cols: list, fps: float) -> tuple:
    """Seconds (f,) and values (f, n) of the data rows, in file order (empty cells → NaN)."""
    times, values = [], []
    for k, r in enumerate(rows[1:], start=1):
        i = line_of[k]
        if len(r) < len(header):
            raise ShapeSpaceError(f"line {i} has {len(r)} cells, the header has {len(header)}", "ragged")
        times.append(parse_timecode(r[t_col], fps))
        vals = []
        for j in cols:
            cell = r[j].strip()
            try:
                vals.append(float(cell) if cell else np.nan)
            except ValueError:
                raise ShapeSpaceError(f"line {i}, column {header[j]!r}: {cell!r} is not a number", "not_number") \
                    from None
        values.append(vals)
    return np.array(times), np.array(values, dtype=np.float64).reshape(len(times), len(cols))


def _fill_and_check(t: np.ndarray, w: np.ndarray, names: list) -> list:
    """Fill NaN cells in ``w`` (in place) from the neighbouring frames; issues for the fills and timecode gaps."""
    issues = []
    bad = ~np.isfinite(w)
    if bad.any():
        for j in np.flatnonzero(bad.any(axis=0)):
            ok = ~bad[:, j]
            if not ok.any():
                raise ShapeSpaceError(f"channel {names[j]!r} has no valid value", "non_finite")
            w[~ok, j] = np.interp(t[~ok], t[ok], w[ok, j])
        issues.append(Issue("warning", "filled_nan", f"filled {int(bad.sum())} missing or NaN values from "
                            "neighbouring frames"))
    step = np.median(np.diff(t))
    gaps = np.flatnonzero(np.diff(t) > 2.5 * step)
    if gaps.size:
        issues.append(Issue("warning", "timecode_gap", f"{gaps.size} gaps in the timecode (largest "
                            f"{np.diff(t).max():.3f} s); values are interpolated across them"))
    return issues


def _read_text(source: str | os.PathLike) -> str:
    if isinstance(source, os.PathLike):
        source = os.fspath(source)
    if isinstance(source, str) and "\n" not in source and len(source) < 4096:
        try:
            with open(source, encoding="utf-8-sig", newline="") as fh:
                return fh.read()
        except FileNotFoundError:
            raise ShapeSpaceError(f"file not found: {source}", "missing_file") from None
        except (OSError, UnicodeDecodeError) as exc:
            raise ShapeSpaceError(f"cannot read {source}: {exc}", "corrupt_file") from None
    return str(source)


def resample(times: ArrayLike, weights: ArrayLike, fps: float, start_frame: float = 1.0,
             fps_base: float = 1.0) -> tuple:
    """Resample a stream onto scene frames ``start_frame, start_frame + 1, …`` at ``fps / fps_base``.

    Linear interpolation in time; the last frame is the last one inside the
    recording.

    Parameters
    ----------
    times : ndarray (f,)
        Increasing sample times in seconds.
    weights : ndarray (f, n)
    fps, fps_base : float
        Scene rate ``fps / fps_base`` frames per second.
    start_frame : float
        Scene frame of the first sample.

    Returns
    -------
    frames : ndarray (g,)
    weights : ndarray (g, n)
    """
    t = np.asarray(times, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    if fps <= 0 or fps_base <= 0:
        raise ShapeSpaceError(f"fps must be positive, got {fps}/{fps_base}", "fps")
    rate = fps / fps_base
    count = int(np.floor((t[-1] - t[0]) * rate + 1e-9)) + 1
    sample_t = t[0] + np.arange(count) / rate
    out = np.stack([np.interp(sample_t, t, w[:, j]) for j in range(w.shape[1])], axis=1)
    return start_frame + np.arange(count, dtype=np.float64), out
