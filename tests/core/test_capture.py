"""core.retarget.capture: Live Link Face timecodes, CSV reading/validation and resampling (thesis 3.5).

References are independent: timecodes are converted by hand (HH·3600 + MM·60 + SS + FF/60), the real
recording is re-read with the ``csv`` module, interpolated values are written out as explicit
arithmetic on the synthetic cells, and resampling is checked against ``np.interp`` at ``t = k / fps``.
"""
import csv
import math
from pathlib import Path

import numpy as np
import pytest

from core.names import ARKIT_52
from core.result import ShapeSpaceError
from core.retarget.capture import WeightStream, parse_timecode, read_live_link_csv, resample

REPO = Path(__file__).resolve().parents[2]
LLF_CSV = REPO / "assets" / "llf_fbhead" / "MySlate_3_Jason_Millers_iPhone.csv"
HEAD_COLUMNS = ("HeadYaw", "HeadPitch", "HeadRoll", "LeftEyeYaw", "LeftEyePitch", "LeftEyeRoll",
                "RightEyeYaw", "RightEyePitch", "RightEyeRoll")


# --------------------------------------------------------------------------- helpers
def tc(frame, base_seconds=9 * 60 + 3, sub=".000"):
    """Timecode text for ``frame`` 60-fps frames after 00:09:03:00 (hand formatting, no core code)."""
    sec, ff = divmod(int(frame), 60)
    total = base_seconds + sec
    h, rem = divmod(total, 3600)
    m, s = divmod(rem, 60)
    return f"{h:02d}:{m:02d}:{s:02d}:{ff:02d}{sub}"


def csv_text(header, rows):
    lines = [",".join(header)]
    lines += [",".join(str(c) for c in r) for r in rows]
    return "\n".join(lines) + "\n"


def issue(stream, code):
    found = [i for i in stream.issues if i.code == code]
    return found[0] if found else None


def codes(stream):
    return {i.code for i in stream.issues}


# --------------------------------------------------------------------------- parse_timecode
@pytest.mark.parametrize("text, seconds", [
    ("00:00:00:00", 0.0),
    ("00:00:00:30", 30 / 60),
    ("00:00:01:00", 1.0),
    ("00:00:00:07.867", 7.867 / 60),
    ("00:32:09:07.867", 32 * 60 + 9 + 7.867 / 60),
    ("01:02:03:04.5", 3600 + 2 * 60 + 3 + 4.5 / 60),
    ("  10:59:59:59.999 ", 10 * 3600 + 59 * 60 + 59 + 59.999 / 60),
])
def test_parse_timecode_hand_values(text, seconds):
    assert parse_timecode(text) == pytest.approx(seconds, rel=0, abs=1e-12)


def test_parse_timecode_other_rate():
    # 24 fps timecode: frame 12 is half a second
    assert parse_timecode("00:00:02:12", fps=24.0) == pytest.approx(2.5, abs=1e-12)


@pytest.mark.parametrize("text", ["", "00:00:00", "00:00:00:00:00", "aa:bb:cc:dd", "00:00:00:x",
                                  "00:00:1.5:00", "00;00;00;00", "00:00:00:nan", "00:00:00:inf"])
def test_parse_timecode_malformed(text):
    with pytest.raises(ShapeSpaceError) as exc:
        parse_timecode(text)
    assert exc.value.code == "timecode"


@pytest.mark.parametrize("text", ["00:60:00:00", "00:00:60:00", "00:00:00:61", "00:-1:00:00",
                                  "00:00:-1:00", "00:00:00:-1"])
def test_parse_timecode_out_of_range(text):
    with pytest.raises(ShapeSpaceError) as exc:
        parse_timecode(text)
    assert exc.value.code == "timecode"


def test_parse_timecode_frame_equal_to_rate_is_out_of_range():
    with pytest.raises(ShapeSpaceError):
        parse_timecode("00:00:00:60")


def test_parse_timecode_negative_hours_is_out_of_range():
    with pytest.raises(ShapeSpaceError):
        parse_timecode("-1:00:00:00")


# --------------------------------------------------------------------------- the real recording
def _reference_read(path):
    """Independent reading of the recording with the csv module and hand timecode arithmetic."""
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    header, body = rows[0], rows[1:]
    secs = []
    for r in body:
        h, m, s, ff = r[0].split(":")
        secs.append(int(h) * 3600 + int(m) * 60 + int(s) + float(ff) / 60.0)
    return header, body, np.array(secs)


@pytest.fixture(scope="module")
def real_stream():
    return read_live_link_csv(str(LLF_CSV))


def test_real_recording_shape_and_names(real_stream):
    header, body, _ = _reference_read(LLF_CSV)
    assert isinstance(real_stream, WeightStream)
    assert real_stream.weights.shape == (328, 52)
    assert real_stream.times.shape == (328,)
    assert len(body) == 328
    # names are the CSV's own PascalCase columns (Timecode, BlendShapeCount, 52 channels, 9 rotations)
    assert header[:2] == ["Timecode", "BlendShapeCount"]
    assert real_stream.names == header[2:54]
    assert all(n[0].isupper() for n in real_stream.names)
    # every ARKit channel is present exactly once, matched by meaning
    from core.names import canonical_name
    assert sorted(canonical_name(n) for n in real_stream.names) == sorted(ARKIT_52)


def test_real_recording_values_and_times(real_stream):
    header, body, secs = _reference_read(LLF_CSV)
    ref = np.array([[float(c) for c in r[2:54]] for r in body])
    assert np.isfinite(real_stream.weights).all()
    np.testing.assert_array_equal(real_stream.weights, ref)
    assert real_stream.times[0] == 0.0
    np.testing.assert_allclose(real_stream.times, secs - secs[0], rtol=0, atol=1e-9)
    steps = np.diff(real_stream.times)
    assert np.all(steps > 0)
    # 60 fps: each step is one frame (the sub-frame field drifts by at most ~0.001 frame)
    np.testing.assert_allclose(steps, 1 / 60, rtol=0, atol=0.01 / 60)
    assert real_stream.start_timecode == "00:32:09:07.867"


def test_real_recording_issues(real_stream):
    extra = issue(real_stream, "extra_columns")
    assert extra is not None
    assert set(extra.items) == set(HEAD_COLUMNS)
    assert "BlendShapeCount" not in extra.items and "Timecode" not in extra.items
    assert codes(real_stream) == {"extra_columns"}          # nothing missing, filled, reordered or gapped


def test_real_recording_as_text_equals_path(real_stream):
    text = LLF_CSV.read_text(encoding="utf-8")
    s = read_live_link_csv(text)
    np.testing.assert_array_equal(s.weights, real_stream.weights)
    np.testing.assert_array_equal(s.times, real_stream.times)


def test_real_recording_pathlib_path(real_stream):
    s = read_live_link_csv(LLF_CSV)
    np.testing.assert_array_equal(s.weights, real_stream.weights)


# --------------------------------------------------------------------------- synthetic CSVs
def test_missing_channels_listed():
    header = ["Timecode", "BlendShapeCount", "EyeBlinkLeft", "JawOpen"]
    rows = [[tc(k), 2, 0.1 * k, 0.2] for k in range(5)]
    s = read_live_link_csv(csv_text(header, rows))
    assert s.names == ["EyeBlinkLeft", "JawOpen"]
    assert s.weights.shape == (5, 2)
    miss = issue(s, "missing_channels")
    assert miss is not None and miss.severity == "warning"
    expected = [n for n in ARKIT_52 if n not in ("eyeBlinkLeft", "jawOpen")]
    assert list(miss.items) == expected                 # every one of the 50, not just the first few
    assert "50" in miss.message


def test_extra_columns_reported_and_ignored():
    header = ["Timecode", "BlendShapeCount", "JawOpen", "HeadYaw", "Foo"]
    rows = [[tc(k), 1, 0.5, 3.0 + k, "x"] for k in range(4)]
    s = read_live_link_csv(csv_text(header, rows), required=("jawOpen",))
    assert s.names == ["JawOpen"]
    np.testing.assert_array_equal(s.weights, np.full((4, 1), 0.5))
    extra = issue(s, "extra_columns")
    assert extra is not None and set(extra.items) == {"HeadYaw", "Foo"}
    assert issue(s, "missing_channels") is None


def test_renamed_columns_other_convention_matched():
    header = ["Timecode", "eyeBlink_L", "eyeBlink_R", "jawOpen", "mouthSmile.L"]
    rows = [[tc(k), 0.1 * k, 0.2 * k, 0.3, 0.4] for k in range(3)]
    s = read_live_link_csv(csv_text(header, rows))
    assert s.names == ["eyeBlink_L", "eyeBlink_R", "jawOpen", "mouthSmile.L"]
    np.testing.assert_allclose(s.weights[:, 0], [0.0, 0.1, 0.2], atol=1e-15)
    np.testing.assert_allclose(s.weights[:, 1], [0.0, 0.2, 0.4], atol=1e-15)
    miss = issue(s, "missing_channels")
    assert len(miss.items) == 48
    for matched in ("eyeBlinkLeft", "eyeBlinkRight", "jawOpen", "mouthSmileLeft"):
        assert matched not in miss.items
    assert issue(s, "extra_columns") is None


def test_duplicate_channel_in_two_conventions_kept_once():
    header = ["Timecode", "EyeBlinkLeft", "eyeBlink_L", "JawOpen"]
    rows = [[tc(k), 0.1, 0.2, 0.3] for k in range(3)]
    s = read_live_link_csv(csv_text(header, rows))
    assert s.names == ["EyeBlinkLeft", "JawOpen"]


def test_nan_and_empty_cells_filled_linearly_in_time():
    # frames 0 1 2 3 4 5 7 8 (frame 6 absent: the time gap must be honoured by the interpolation)
    frames = [0, 1, 2, 3, 4, 5, 7, 8]
    a = [0.0, 0.3, "", "nan", 0.9, 0.5, "NaN", 0.2]       # fills at frames 2, 3 and 7
    b = ["", 0.4, 0.6, 0.8, 1.0, 0.1, 0.7, ""]          # leading and trailing gaps: held at the nearest value
    header = ["Timecode", "JawOpen", "TongueOut"]
    s = read_live_link_csv(csv_text(header, [[tc(f), x, y] for f, x, y in zip(frames, a, b)]),
                           required=("jawOpen", "tongueOut"))
    assert np.isfinite(s.weights).all()
    # JawOpen: frames 2, 3 between frame 1 (0.3) and frame 4 (0.9): 0.3 + 0.6·(1/3), 0.3 + 0.6·(2/3)
    # frame 7 between frame 5 (0.5) and frame 8 (0.2): 0.5 − 0.3·(2/3)
    expected_a = [0.0, 0.3, 0.5, 0.7, 0.9, 0.5, 0.3, 0.2]
    expected_b = [0.4, 0.4, 0.6, 0.8, 1.0, 0.1, 0.7, 0.7]
    np.testing.assert_allclose(s.weights[:, 0], expected_a, rtol=0, atol=1e-12)
    np.testing.assert_allclose(s.weights[:, 1], expected_b, rtol=0, atol=1e-12)
    filled = issue(s, "filled_nan")
    assert filled is not None and "5" in filled.message    # 3 + 2 cells
    np.testing.assert_allclose(s.times, np.array(frames) / 60, rtol=0, atol=1e-9)


def test_channel_entirely_nan_is_an_error():
    header = ["Timecode", "JawOpen", "TongueOut"]
    rows = [[tc(k), 0.1 * k, "nan" if k % 2 else ""] for k in range(5)]
    with pytest.raises(ShapeSpaceError) as exc:
        read_live_link_csv(csv_text(header, rows))
    assert exc.value.code == "non_finite"
    assert "TongueOut" in str(exc.value)


def test_reversed_rows_are_sorted():
    header = ["Timecode", "JawOpen", "TongueOut"]
    fwd = [[tc(k, sub=".250"), 0.1 * k, 1.0 - 0.05 * k] for k in range(6)]
    s = read_live_link_csv(csv_text(header, fwd[::-1]))
    assert "reversed_timecode" in codes(s)
    np.testing.assert_allclose(s.times, np.arange(6) / 60, rtol=0, atol=1e-9)
    np.testing.assert_allclose(s.weights[:, 0], 0.1 * np.arange(6), atol=1e-15)
    np.testing.assert_allclose(s.weights[:, 1], 1.0 - 0.05 * np.arange(6), atol=1e-15)
    assert s.start_timecode == tc(0, sub=".250")


def test_in_order_rows_have_no_reorder_issue():
    header = ["Timecode", "JawOpen"]
    s = read_live_link_csv(csv_text(header, [[tc(k), 0.1] for k in range(4)]))
    assert "reversed_timecode" not in codes(s) and "repeated_timecode" not in codes(s)


def test_repeated_timecode_rows_dropped():
    header = ["Timecode", "JawOpen"]
    frames = [0, 1, 1, 2, 3, 3, 3, 4]
    vals = [0.0, 0.1, 0.1, 0.2, 0.3, 0.3, 0.3, 0.4]
    s = read_live_link_csv(csv_text(header, [[tc(f), v] for f, v in zip(frames, vals)]),
                           required=("jawOpen",))
    rep = issue(s, "repeated_timecode")
    assert rep is not None and "3" in rep.message
    np.testing.assert_allclose(s.times, np.arange(5) / 60, rtol=0, atol=1e-9)
    np.testing.assert_allclose(s.weights[:, 0], [0.0, 0.1, 0.2, 0.3, 0.4], atol=1e-15)


def test_repeated_rows_leaving_two_frames_is_too_short():
    header = ["Timecode", "JawOpen"]
    rows = [[tc(0), 0.0], [tc(1), 0.1], [tc(1), 0.1], [tc(0), 0.0]]
    with pytest.raises(ShapeSpaceError) as exc:
        read_live_link_csv(csv_text(header, rows))
    assert exc.value.code == "too_short"


def test_timecode_gap_reported():
    header = ["Timecode", "JawOpen"]
    frames = list(range(10)) + list(range(20, 30))
    s = read_live_link_csv(csv_text(header, [[tc(f), 0.01 * f] for f in frames]))
    gap = issue(s, "timecode_gap")
    assert gap is not None and gap.message.startswith("1 gap")
    np.testing.assert_allclose(s.times, np.array(frames) / 60, rtol=0, atol=1e-9)
    assert s.weights.shape == (20, 1)


def test_small_jitter_is_not_a_gap():
    header = ["Timecode", "JawOpen"]
    # steps of 1 and 2 frames (2 < 2.5 periods): no gap
    frames = [0, 1, 2, 4, 5, 6, 8, 9]
    s = read_live_link_csv(csv_text(header, [[tc(f), 0.5] for f in frames]))
    assert "timecode_gap" not in codes(s)


def test_gap_across_minute_boundary_in_timecode():
    # 00:09:03:58, :59, 00:09:04:00, :01 — consecutive frames across a second boundary
    header = ["Timecode", "JawOpen"]
    s = read_live_link_csv(csv_text(header, [[tc(f), 0.5] for f in range(58, 62)]))
    np.testing.assert_allclose(s.times, np.arange(4) / 60, rtol=0, atol=1e-9)
    assert "timecode_gap" not in codes(s)


@pytest.mark.parametrize("count", [1, 2])
def test_fewer_than_three_frames(count):
    header = ["Timecode", "JawOpen"]
    with pytest.raises(ShapeSpaceError) as exc:
        read_live_link_csv(csv_text(header, [[tc(k), 0.1] for k in range(count)]))
    assert exc.value.code == "too_short"


def test_no_timecode_column():
    text = csv_text(["Time", "JawOpen"], [[k, 0.1] for k in range(5)])
    with pytest.raises(ShapeSpaceError) as exc:
        read_live_link_csv(text)
    assert exc.value.code == "no_timecode"


def test_no_arkit_column():
    text = csv_text(["Timecode", "BlendShapeCount", "HeadYaw"], [[tc(k), 0, 0.1] for k in range(5)])
    with pytest.raises(ShapeSpaceError) as exc:
        read_live_link_csv(text)
    assert exc.value.code == "no_channels"


def test_empty_text():
    with pytest.raises(ShapeSpaceError) as exc:
        read_live_link_csv("\n\n")
    assert exc.value.code == "empty"


def test_non_number_cell_names_line_and_column():
    header = ["Timecode", "JawOpen", "TongueOut"]
    rows = [[tc(0), 0.1, 0.2], [tc(1), 0.1, 0.2], [tc(2), 0.1, "oops"], [tc(3), 0.1, 0.2]]
    with pytest.raises(ShapeSpaceError) as exc:
        read_live_link_csv(csv_text(header, rows))
    assert exc.value.code == "not_number"
    msg = str(exc.value)
    assert "line 4" in msg                     # header is line 1, so the third data row is line 4
    assert "TongueOut" in msg and "oops" in msg


def test_non_number_cell_line_number_counts_blank_lines():
    text = ("Timecode,JawOpen\n"                   # line 1
            f"{tc(0)},0.1\n"                      # line 2
            "\n"                                   # line 3 (blank)
            f"{tc(1)},0.1\n"                      # line 4
            f"{tc(2)},bad\n")                     # line 5
    with pytest.raises(ShapeSpaceError) as exc:
        read_live_link_csv(text)
    assert "line 5" in str(exc.value)


def test_bad_timecode_cell_is_an_error():
    header = ["Timecode", "JawOpen"]
    rows = [[tc(0), 0.1], ["00:00:xx:00", 0.1], [tc(2), 0.1]]
    with pytest.raises(ShapeSpaceError) as exc:
        read_live_link_csv(csv_text(header, rows))
    assert exc.value.code == "timecode"


def test_ragged_row_is_an_error():
    text = csv_text(["Timecode", "JawOpen", "TongueOut"], [[tc(0), 0.1, 0.2], [tc(1), 0.1], [tc(2), 0.1, 0.2]])
    with pytest.raises(ShapeSpaceError) as exc:
        read_live_link_csv(text)
    assert exc.value.code == "ragged"


def test_missing_file(tmp_path):
    with pytest.raises(ShapeSpaceError) as exc:
        read_live_link_csv(str(tmp_path / "nope.csv"))
    assert exc.value.code == "missing_file"


def test_file_with_bom_is_read(tmp_path):
    path = tmp_path / "bom.csv"
    path.write_text(csv_text(["Timecode", "JawOpen"], [[tc(k), 0.25] for k in range(3)]), encoding="utf-8-sig")
    s = read_live_link_csv(str(path))
    assert s.names == ["JawOpen"]
    np.testing.assert_array_equal(s.weights, np.full((3, 1), 0.25))


# --------------------------------------------------------------------------- resample
@pytest.mark.parametrize("fps", [24.0, 30.0, 25.0])
def test_resample_60fps_stream_matches_interp(fps):
    rng = np.random.default_rng(int(fps))
    F = 121                                     # exactly 2 s at 60 fps
    t = np.arange(F) / 60.0
    w = rng.uniform(0, 1, (F, 4))
    frames, out = resample(t, w, fps, start_frame=1.0)
    count = int(2 * fps) + 1                    # k = 0 … 2·fps, the last one at t = 2 s exactly
    np.testing.assert_array_equal(frames, 1.0 + np.arange(count))
    ts = np.arange(count) / fps
    ref = np.stack([np.interp(ts, t, w[:, j]) for j in range(4)], axis=1)
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-12)


def test_resample_hand_values_24fps():
    t = np.arange(13) / 60.0                    # 0.2 s
    w = np.arange(13, dtype=float)[:, None] ** 2   # w_i = i² at sample i
    frames, out = resample(t, w, 24.0)
    # scene frame k at t = k/24 = 2.5k/60: halfway samples for odd k, exact samples for even k
    # k=0: 0; k=1: (2²+3²)/2 = 6.5; k=2: 5² = 25; k=3: (7²+8²)/2 = 56.5; k=4: 10² = 100
    np.testing.assert_array_equal(frames, [1.0, 2.0, 3.0, 4.0, 5.0])
    np.testing.assert_allclose(out[:, 0], [0.0, 6.5, 25.0, 56.5, 100.0], rtol=0, atol=1e-12)


def test_resample_start_frame_and_offset_times():
    t = 3.0 + np.arange(7) / 60.0                 # a stream not starting at 0
    w = 2.0 * (t - 3.0)[:, None]                  # linear ramp: resampled value = 2·k/fps
    frames, out = resample(t, w, 30.0, start_frame=101.0)
    np.testing.assert_array_equal(frames, [101.0, 102.0, 103.0, 104.0])
    np.testing.assert_allclose(out[:, 0], 2.0 * np.arange(4) / 30.0, rtol=0, atol=1e-12)


def test_resample_ntsc_rate():
    t = np.arange(61) / 60.0
    w = np.sin(3 * t)[:, None]
    frames, out = resample(t, w, 30000.0, start_frame=0.0, fps_base=1001.0)
    ts = np.arange(frames.size) * 1001.0 / 30000.0
    assert frames.size == math.floor(30000.0 / 1001.0) + 1          # 29.97 frames per 1 s
    np.testing.assert_allclose(out[:, 0], np.interp(ts, t, w[:, 0]), rtol=0, atol=1e-12)


def test_resample_real_recording(real_stream):
    frames, out = resample(real_stream.times, real_stream.weights, 24.0)
    T = real_stream.times[-1]
    assert frames.size == math.floor(T * 24) + 1
    ts = np.arange(frames.size) / 24.0
    assert ts[-1] <= T
    ref = np.stack([np.interp(ts, real_stream.times, real_stream.weights[:, j]) for j in range(52)], axis=1)
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-12)


@pytest.mark.parametrize("fps, base", [(0.0, 1.0), (-24.0, 1.0), (24.0, 0.0), (24.0, -1.0)])
def test_resample_non_positive_rate(fps, base):
    with pytest.raises(ShapeSpaceError) as exc:
        resample(np.arange(5) / 60.0, np.zeros((5, 2)), fps, fps_base=base)
    assert exc.value.code == "fps"


# --------------------------------------------------------------------------- hardening (#10: r09, r13, r15, r24, r28)
def _take(first_seconds, count, header=("Timecode", "JawOpen")):
    """``count`` 60-fps rows from ``first_seconds`` of the day (wrapping at midnight, hand formatting)."""
    rows = []
    for k in range(count):
        t = (first_seconds * 60 + k) % (86400 * 60)
        sec, ff = divmod(t, 60)
        rows.append([f"{sec // 3600:02d}:{sec // 60 % 60:02d}:{sec % 60:02d}:{ff:02d}.000", 0.01 * k])
    return csv_text(header, rows)


def test_take_crossing_midnight_continues_the_day():
    s = read_live_link_csv(_take(86400 - 2, 300))               # 23:59:58 … 00:00:02.98
    np.testing.assert_allclose(s.times, np.arange(300) / 60, rtol=0, atol=1e-9)
    np.testing.assert_allclose(s.weights[:, 0], 0.01 * np.arange(300), atol=1e-12)
    assert s.start_timecode == "23:59:58:00.000"
    assert "midnight" in codes(s) and "line 122" in issue(s, "midnight").message
    assert "reversed_timecode" not in codes(s) and "timecode_gap" not in codes(s)


@pytest.mark.parametrize("bad", ["25:32:09:07.000", "99999:00:00:00.000", "24:00:00:00"])
def test_impossible_hour_is_refused_with_its_line(bad):
    text = _take(9 * 60, 10).splitlines()
    text[6] = bad + ",0.5"                                         # line 7
    with pytest.raises(ShapeSpaceError) as exc:
        read_live_link_csv("\n".join(text) + "\n")
    assert exc.value.code == "timecode" and str(exc.value).startswith("line 7: ") and bad in str(exc.value)


def test_parse_timecode_hour_24_is_out_of_range():
    with pytest.raises(ShapeSpaceError):
        parse_timecode("24:00:00:00")
    assert parse_timecode("23:59:59:59") == pytest.approx(86399 + 59 / 60)


def test_one_row_hours_away_is_refused_naming_the_lines():
    text = _take(9 * 60, 10).splitlines()
    text[4] = "03:00:00:00.000,0.5"                                # line 5: hours after the take
    with pytest.raises(ShapeSpaceError) as exc:
        read_live_link_csv("\n".join(text) + "\n")
    assert exc.value.code == "timecode" and "line 5" in str(exc.value) and "2.8 h" in str(exc.value)


def test_take_longer_than_the_limit_is_refused(monkeypatch):
    import core.retarget.capture as capture
    monkeypatch.setattr(capture, "MAX_TAKE_SECONDS", 2.0)
    with pytest.raises(ShapeSpaceError) as exc:
        read_live_link_csv(_take(0, 200))
    assert exc.value.code == "too_large" and "3.3 s" in str(exc.value)


@pytest.mark.parametrize("ending", ["\r", "\r\n", "\n"])
def test_any_line_ending_is_read(ending):
    text = _take(60, 5).replace("\n", ending)
    s = read_live_link_csv(text if ending != "\r" else text + "\n")
    np.testing.assert_allclose(s.weights[:, 0], 0.01 * np.arange(5), atol=1e-12)


def test_cr_only_file_is_read(tmp_path):
    path = tmp_path / "cr.csv"
    path.write_bytes(_take(60, 5).replace("\n", "\r").encode())
    assert read_live_link_csv(path).times.size == 5


@pytest.mark.parametrize("body, line", [
    ('"' + _take(60, 6000), 1),                                           # a stray quote at the top
    ("Timecode,JawOpen\n00:00:00:00.000," + "1" * 200000 + "\n", 2),      # a 200 KB cell
])
def test_malformed_csv_is_a_shapespace_error_naming_file_and_line(tmp_path, body, line):
    path = tmp_path / "bad.csv"
    path.write_text(body, newline="")
    with pytest.raises(ShapeSpaceError) as exc:
        read_live_link_csv(path)
    assert str(exc.value).startswith(f"{path}: line {line}: ") and exc.value.code == "corrupt_file"


def test_content_errors_from_a_file_name_the_file(tmp_path):
    path = tmp_path / "take.csv"
    path.write_text(csv_text(["Timecode", "JawOpen"], [[tc(0), 0.1], [tc(1), "x"], [tc(2), 0.1]]))
    with pytest.raises(ShapeSpaceError) as exc:
        read_live_link_csv(path)
    assert str(exc.value).startswith(f"{path}: line 3, column 'JawOpen'")


def test_not_utf8_names_the_line(tmp_path):
    path = tmp_path / "latin1.csv"
    path.write_bytes(_take(60, 5).encode() + b"00:01:00:09.000,caf\xe9\n")
    with pytest.raises(ShapeSpaceError) as exc:
        read_live_link_csv(path)
    assert exc.value.code == "corrupt_file" and "line 7: not UTF-8" in str(exc.value)


def test_huge_weight_is_refused_naming_line_and_column():
    text = csv_text(["Timecode", "JawOpen", "TongueOut"], [[tc(k), 0.1, "1e308" if k == 2 else 0.2]
                                                           for k in range(5)])
    with pytest.raises(ShapeSpaceError) as exc:
        read_live_link_csv(text)
    assert exc.value.code == "range" and str(exc.value).startswith("line 4, column 'TongueOut': 1e308")


def test_weights_outside_zero_one_are_reported_by_channel():
    text = csv_text(["Timecode", "JawOpen", "TongueOut", "EyeBlinkLeft"],
                    [[tc(k), 0.1 * k, 3.0 if k == 1 else 0.2, -0.5 if k == 2 else 0.0] for k in range(5)])
    s = read_live_link_csv(text)
    out = issue(s, "weights_out_of_range")
    assert out is not None and out.items == ("TongueOut", "EyeBlinkLeft")
    assert "TongueOut (0.2 … 3)" in out.message and "EyeBlinkLeft (-0.5 … 0)" in out.message
    assert "weights_out_of_range" not in codes(read_live_link_csv(str(LLF_CSV)))


def test_directory_fifo_and_device_are_refused_without_blocking(tmp_path):
    import os
    folder = tmp_path / "dir.csv"
    folder.mkdir()
    with pytest.raises(ShapeSpaceError) as exc:
        read_live_link_csv(folder)
    assert exc.value.code == "not_a_file" and "is a directory" in str(exc.value)
    if hasattr(os, "mkfifo"):
        fifo = tmp_path / "fifo.csv"
        os.mkfifo(fifo)
        with pytest.raises(ShapeSpaceError) as exc:          # returns at once: opened without blocking
            read_live_link_csv(str(fifo))
        assert exc.value.code == "not_a_file" and "not a regular file" in str(exc.value)
    if os.path.exists("/dev/zero"):
        with pytest.raises(ShapeSpaceError) as exc:
            read_live_link_csv("/dev/zero")
        assert exc.value.code == "not_a_file"


def test_file_larger_than_the_limit_is_refused(tmp_path, monkeypatch):
    import core.retarget.capture as capture
    monkeypatch.setattr(capture, "MAX_FILE_BYTES", 100)
    path = tmp_path / "big.csv"
    path.write_text(_take(60, 20))
    with pytest.raises(ShapeSpaceError) as exc:
        read_live_link_csv(path)
    assert exc.value.code == "too_large" and str(path) in str(exc.value)


def test_path_with_a_line_break_is_a_path(tmp_path):
    path = tmp_path / "take\none.csv"
    path.write_text(_take(60, 5))
    assert read_live_link_csv(str(path)).times.size == 5


def test_resample_refuses_more_than_the_memory_budget(monkeypatch):
    import core.retarget.capture as capture
    monkeypatch.setattr(capture, "MAX_RESAMPLE_BYTES", 1000)
    t = np.arange(61) / 60.0
    frames, _ = resample(t, np.zeros((61, 2)), 30.0)              # 31 frames × 2 × 8 = 496 bytes
    assert frames.size == 31
    with pytest.raises(ShapeSpaceError) as exc:
        resample(t, np.zeros((61, 5)), 30.0)
    assert exc.value.code == "too_large"


@pytest.mark.parametrize("times", [[0.0, np.nan, 1.0], [0.0, 2.0, 1.0], [0.0, 0.0, 1.0]])
def test_resample_refuses_bad_times(times):
    with pytest.raises(ShapeSpaceError):
        resample(np.array(times), np.zeros((3, 1)), 30.0)
