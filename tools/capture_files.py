"""Capture recordings of each supported app written from a known take, following each format's documentation.

Used by the tests (round trips) and the retarget benchmark (reading speed); written independently of
:mod:`core.retarget.formats` (names respelled by hand, angles converted by hand).  A take is
``(names, times, weights, rotations)``: Live Link Face PascalCase names (52), times in seconds (f,),
weights (f, 52), head / left-eye / right-eye ``(yaw, pitch, roll)`` radians (f, 9).
"""
import csv
import json

import numpy as np

__all__ = ["load_llf_take", "long_take", "facecap_name", "arkit_name", "write_facecap", "write_ifacialmocap",
           "write_audio2face", "write_mediapipe_json", "write_mediapipe_csv", "write_llf_csv", "WRITERS"]


def load_llf_take(path, head_motion: bool = True) -> tuple:
    """The Live Link Face CSV at ``path`` read by hand (csv module, ``HH·3600 + MM·60 + SS + FF/60``); with
    ``head_motion`` a synthetic nod and turn on the head columns (the shared take's are all 0)."""
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    header, body = rows[0], rows[1:]
    secs = []
    for r in body:
        h, m, s, f = r[0].split(":")
        secs.append(int(h) * 3600 + int(m) * 60 + int(s) + float(f) / 60)
    t = np.array(secs) - secs[0]
    names = header[2:54]
    w = np.array([[float(c) for c in r[2:54]] for r in body])
    rot = np.array([[float(c) for c in r[54:63]] for r in body])
    if head_motion:
        k = np.arange(t.size)
        rot[:, 0] = 0.4 * np.sin(k / 17)
        rot[:, 1] = 0.2 * np.cos(k / 23)
        rot[:, 2] = 0.1 * np.sin(k / 31)
    return names, t, w, rot


def long_take(take, frames: int) -> tuple:
    """``take`` repeated (back and forth, so it stays smooth) to ``frames`` samples at 60 fps."""
    names, _, w, rot = take
    idx = np.arange(frames) % (2 * w.shape[0] - 2)
    idx = np.where(idx < w.shape[0], idx, 2 * w.shape[0] - 2 - idx)
    return names, np.arange(frames) / 60.0, w[idx], rot[idx]


def write_llf_csv(take) -> str:
    """A Live Link Face CSV: Timecode (HH:MM:SS:FF.fff at 60 fps), BlendShapeCount, 52 weights, 9 rotations."""
    names, t, w, rot = take
    lines = [",".join(["Timecode", "BlendShapeCount", *names, "HeadYaw", "HeadPitch", "HeadRoll", "LeftEyeYaw",
                       "LeftEyePitch", "LeftEyeRoll", "RightEyeYaw", "RightEyePitch", "RightEyeRoll"])]
    for f in range(t.size):
        milli = int(round(t[f] * 60000.0))                  # thousandths of a 60-fps frame
        whole, rest = divmod(milli, 60000)
        h, m, s = whole // 3600, whole // 60 % 60, whole % 60
        ff, frac = divmod(rest, 1000)
        lines.append(",".join([f"{h:02d}:{m:02d}:{s:02d}:{ff:02d}.{frac:03d}", "61",
                               *(repr(float(v)) for v in w[f]), *(repr(float(v)) for v in rot[f])]))
    return "\n".join(lines) + "\n"


def facecap_name(llf):
    """``EyeBlinkLeft`` → ``eyeBlink_L`` (Face Cap / iFacialMocap spelling), by hand."""
    base = llf[0].lower() + llf[1:]
    for side, tag in (("Left", "_L"), ("Right", "_R")):
        if base.endswith(side):
            return base[:-len(side)] + tag
    return base


def arkit_name(llf):
    return llf[0].lower() + llf[1:]


# --------------------------------------------------------------------------- writers (by the documentation)
def write_facecap(take):
    names, t, w, rot = take
    deg = np.degrees(rot)
    lines = ["info,version,1.0", "bs," + ",".join(facecap_name(n) for n in names)]
    for f in range(t.size):
        head = [0.0, 0.0, 0.0, deg[f, 1], deg[f, 0], deg[f, 2]]           # x pitch, y yaw, z roll
        eyes = [deg[f, 4], deg[f, 3], deg[f, 7], deg[f, 6]]                 # left x, y; right x, y
        lines.append("k," + ",".join([f"{t[f] * 1000:.6f}"] + [repr(float(v)) for v in head + eyes]
                                     + [repr(float(v)) for v in w[f]]))
    return "\n".join(lines) + "\n"


def write_ifacialmocap(take, tcp=False):
    names, t, w, rot = take
    deg = np.degrees(rot)
    frames = []
    for f in range(t.size):
        parts = [f"{facecap_name(n)}&{float(100 * w[f, j])!r}" for j, n in enumerate(names)]
        parts.append("=head#" + ",".join(repr(float(v)) for v in (deg[f, 1], deg[f, 0], deg[f, 2], 0, 0, 0)))
        parts.append("rightEye#" + ",".join(repr(float(v)) for v in (deg[f, 7], deg[f, 6], deg[f, 8])))
        parts.append("leftEye#" + ",".join(repr(float(v)) for v in (deg[f, 4], deg[f, 3], deg[f, 5])))
        frames.append("|".join(parts) + "|")
    return "___iFacialMocap".join(frames) + "___iFacialMocap" if tcp else "\n".join(frames) + "\n"


def write_audio2face(take, fps=60):
    names, t, w, _ = take
    return json.dumps({"exportFps": fps, "trackPath": "/World/audio2face/Player", "numPoses": len(names),
                       "numFrames": t.size, "facsNames": [arkit_name(n) for n in names],
                       "weightMat": w.tolist()})


def mp_names(names) -> list:
    """MediaPipe's categories: ``_neutral`` and the ARKit names but ``tongueOut``."""
    return ["_neutral"] + [arkit_name(n) for n in names if n != "TongueOut"]


def write_mediapipe_json(take):
    names, t, w, _ = take
    frames = []
    for f in range(t.size):
        cats = [{"index": 0, "score": 0.5, "category_name": "_neutral", "display_name": ""}]
        cats += [{"index": j + 1, "score": float(w[f, j]), "category_name": arkit_name(n), "display_name": ""}
                 for j, n in enumerate(names) if n != "TongueOut"]
        frames.append({"timestamp_ms": float(t[f] * 1000), "face_blendshapes": [cats]})
    return json.dumps(frames)


def write_mediapipe_csv(take):
    names, t, w, _ = take
    keep = [j for j, n in enumerate(names) if n != "TongueOut"]
    lines = [",".join(["timestamp_ms"] + mp_names(names))]
    for f in range(t.size):
        lines.append(",".join([repr(float(t[f] * 1000)), "0.5"] + [repr(float(w[f, j])) for j in keep]))
    return "\n".join(lines) + "\n"




WRITERS = {"llf_csv": write_llf_csv, "facecap_txt": write_facecap, "ifacialmocap": write_ifacialmocap,
           "audio2face_json": write_audio2face, "mediapipe_json": write_mediapipe_json,
           "mediapipe_csv": write_mediapipe_csv}
