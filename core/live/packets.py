"""Decoding (and, for tests and replays, encoding) of the live capture protocols that need no library.

- **Live Link Face** "Live Link (ARKit)" UDP packets, version 6 (default port 11111), as the public
  decoders document them (all multi-byte fields big-endian)::

      uint8   version (6)
      int32   length, then that many bytes: device id (a UUID)
      int32   length, then that many bytes: subject name
      int32   frame number          ┐ the frame time: (frame + sub-frame) / (fps / denominator)
      float32 sub-frame (0 … 1)     │
      int32   fps, int32 denominator┘
      uint8   count (61)
      float32 × count: 52 blendshapes in the ARKit enum order, head yaw/pitch/roll, left and right eye
                       yaw/pitch/roll (:data:`~.frames.LLF_CURVES`)

  A packet that stops after the subject name is the app's "no face" packet.
- **iFacialMocap**'s UDP text (default port 49983): ``name-value|…|=head#rx,ry,rz,px,py,pz|
  rightEye#rx,ry,rz|leftEye#rx,ry,rz|`` with values 0 … 100 (version 2 writes ``name&value``), angles in
  degrees (``rx`` pitch, ``ry`` yaw, ``rz`` roll).
- **Face Cap**'s OSC messages are parsed by python-osc in the bridge; :class:`FaceCapAssembler` turns the
  parsed messages (``/W`` index value, ``/HR`` or ``/HRQ``, ``/HT``, ``/ELR``, ``/ERR``) into frames.

Every decoder validates everything and raises :class:`~core.result.ShapeSpaceError` (code
``malformed_packet``) with a one-line reason; the receiver counts those and carries on.
"""
from __future__ import annotations

import math
import struct
from collections.abc import Sequence

import numpy as np

from ..errors import ErrorCode
from ..headpose import eye_ypr_from_degrees, ypr_from_degrees
from ..names import canonical_name
from ..result import ShapeSpaceError
from .frames import FACECAP_52, LLF_BLENDSHAPES, LLF_CURVES, LiveFrame

__all__ = ["LLF_PORT", "LLF_VERSION", "IFM_PORT", "FACECAP_PORT", "MAX_DATAGRAM", "encode_llf", "decode_llf",
           "encode_ifacialmocap", "decode_ifacialmocap", "FaceCapAssembler", "quaternion_to_yaw_pitch_roll",
           "ypr_from_degrees", "eye_ypr_from_degrees"]

LLF_PORT = 11111
LLF_VERSION = 6
IFM_PORT = 49983
FACECAP_PORT = 8080
#: Largest datagram a receiver reads (the UDP maximum).
MAX_DATAGRAM = 65536
#: Longest device id / subject name accepted in a Live Link Face packet.
MAX_NAME = 256
_LLF_COUNT = len(LLF_CURVES)
_LLF_FLOATS = struct.Struct(f">{_LLF_COUNT}f")
_LLF_TIME = struct.Struct(">ifiiB")


def _bad(reason: str) -> ShapeSpaceError:
    return ShapeSpaceError(reason, ErrorCode.MALFORMED_PACKET)


# ------------------------------------------------------------------ Live Link Face
def encode_llf(values: Sequence[float], frame: int, subframe: float = 0.0, fps: int = 60, denominator: int = 1,
               device_id: str = "00000000-0000-0000-0000-000000000000", subject: str = "iPhone",
               version: int = LLF_VERSION, count: int | None = None) -> bytes:
    """A Live Link Face v6 packet carrying ``values`` (61 curves in :data:`~.frames.LLF_CURVES` order).

    ``version`` and ``count`` may be set to other values to build malformed packets in tests.
    """
    vals = [float(v) for v in values]
    dev, subj = device_id.encode("utf-8"), subject.encode("utf-8")
    head = struct.pack(">B", version) + struct.pack(">i", len(dev)) + dev + struct.pack(">i", len(subj)) + subj
    n = len(vals) if count is None else count
    return head + _LLF_TIME.pack(int(frame), float(subframe), int(fps), int(denominator), n) + \
        struct.pack(f">{len(vals)}f", *vals)


def _string(data: bytes, at: int, what: str) -> tuple:
    if len(data) < at + 4:
        raise _bad(f"Live Link Face packet truncated in its {what} ({len(data)} bytes)")
    (n,) = struct.unpack_from(">i", data, at)
    if not 0 <= n <= MAX_NAME or len(data) < at + 4 + n:
        raise _bad(f"Live Link Face packet has a {what} of impossible length {n} ({len(data)} bytes)")
    return data[at + 4:at + 4 + n].decode("utf-8", errors="replace"), at + 4 + n


def decode_llf(data: bytes, arrival: float = 0.0) -> LiveFrame | None:
    """A Live Link Face v6 packet → :class:`~.frames.LiveFrame` (``None`` for a "no face" packet).

    Parameters
    ----------
    data : bytes
        One UDP datagram.
    arrival : float
        Receive time (monotonic seconds), stored on the frame.

    Returns
    -------
    LiveFrame or None
        ``weights`` (52,) in :data:`~.frames.LLF_BLENDSHAPES` order, head and eye rotations in radians,
        ``time = (frame + subframe) · denominator / fps`` seconds, ``frame`` and ``rate`` the counter.

    Raises
    ------
    ShapeSpaceError
        ``malformed_packet``: empty, wrong version, truncated, impossible lengths, a count other than 61,
        trailing bytes, non-finite values or a non-positive rate.
    """
    if not data:
        raise _bad("empty datagram")
    if data[0] != LLF_VERSION:
        raise _bad(f"Live Link Face packet version {data[0]}, expected {LLF_VERSION}")
    _, at = _string(data, 1, "device id")
    subject, at = _string(data, at, "subject name")
    if at == len(data):
        return None
    if len(data) < at + _LLF_TIME.size:
        raise _bad(f"Live Link Face packet truncated in its frame time ({len(data)} bytes)")
    frame, subframe, fps, den, count = _LLF_TIME.unpack_from(data, at)
    at += _LLF_TIME.size
    if count != _LLF_COUNT:
        raise _bad(f"Live Link Face packet has {count} curves, expected {_LLF_COUNT}")
    if len(data) != at + _LLF_FLOATS.size:
        raise _bad(f"Live Link Face packet has {len(data) - at} bytes of curves, expected {_LLF_FLOATS.size}")
    if fps <= 0 or den <= 0 or not math.isfinite(subframe) or not 0.0 <= subframe < 1.0:
        raise _bad(f"Live Link Face packet has an impossible frame time (rate {fps}/{den}, sub-frame {subframe})")
    values = np.array(_LLF_FLOATS.unpack_from(data, at), dtype=np.float64)
    if not np.isfinite(values).all():
        bad = LLF_CURVES[int(np.flatnonzero(~np.isfinite(values))[0])]
        raise _bad(f"Live Link Face packet has a non-finite {bad}")
    rate = fps / den
    return LiveFrame(LLF_BLENDSHAPES, values[:52], head=values[52:55].copy(), eye_left=values[55:58].copy(),
                     eye_right=values[58:61].copy(), time=(frame + subframe) / rate, frame=int(frame), rate=rate,
                     arrival=arrival, subject=subject)


# ------------------------------------------------------------------ iFacialMocap
_IFM_INDEX = {canonical_name(n): i for i, n in enumerate(FACECAP_52)}
_IFM_MAX_FIELDS = 160


def _numbers(text: str, count: int, what: str) -> np.ndarray:
    parts = text.split(",")
    if len(parts) != count:
        raise _bad(f"iFacialMocap {what} has {len(parts)} numbers, expected {count}")
    try:
        vals = np.array([float(p) for p in parts])
    except ValueError:
        raise _bad(f"iFacialMocap {what} is not numeric: {text[:40]!r}") from None
    if not np.isfinite(vals).all():
        raise _bad(f"iFacialMocap {what} is not finite")
    return vals


def encode_ifacialmocap(weights: Sequence[float], head_degrees: Sequence[float] = (0, 0, 0),
                        position: Sequence[float] = (0, 0, 0), right_eye: Sequence[float] = (0, 0, 0),
                        left_eye: Sequence[float] = (0, 0, 0), separator: str = "&") -> bytes:
    """An iFacialMocap text datagram for weights (52,) in :data:`~.frames.FACECAP_52` order (0 … 1)."""
    parts = [f"{n}{separator}{100.0 * float(w):.6g}" for n, w in zip(FACECAP_52, weights)]
    parts.append("=head#" + ",".join(f"{float(v):.9g}" for v in (*head_degrees, *position)))
    parts.append("rightEye#" + ",".join(f"{float(v):.9g}" for v in right_eye))
    parts.append("leftEye#" + ",".join(f"{float(v):.9g}" for v in left_eye))
    return ("|".join(parts) + "|").encode("ascii")


def decode_ifacialmocap(data: bytes, arrival: float = 0.0) -> LiveFrame:
    """An iFacialMocap datagram → :class:`~.frames.LiveFrame` (``time`` is the arrival time).

    Blendshapes are matched by name (any spelling :func:`core.names.canonical_name` knows) into
    :data:`~.frames.FACECAP_52` order; channels the packet does not carry are 0; unknown names are ignored.

    Raises
    ------
    ShapeSpaceError
        ``malformed_packet``: not text, no head pose or no blendshape, a field that is neither, bad numbers,
        duplicates, too many fields.
    """
    try:
        text = data.decode("ascii").strip().rstrip("\0")
    except UnicodeDecodeError:
        raise _bad("iFacialMocap packet is not ASCII text") from None
    fields = [f.strip() for f in text.split("|") if f.strip()]
    if len(fields) > _IFM_MAX_FIELDS:
        raise _bad(f"iFacialMocap packet has {len(fields)} fields (at most {_IFM_MAX_FIELDS})")
    weights = np.zeros(len(FACECAP_52))
    seen, poses = set(), {}
    for f in fields:
        for tag, count in (("=head#", 6), ("rightEye#", 3), ("leftEye#", 3)):
            if f.startswith(tag):
                if tag in poses:
                    raise _bad(f"iFacialMocap packet repeats {tag.strip('=#')}")
                poses[tag] = _numbers(f[len(tag):], count, tag.strip("=#"))
                break
        else:
            name, sep, value = f.partition("&") if "&" in f else f.partition("-")
            if not sep or not name or len(name) > 64 or not name.replace("_", "").isalnum():
                raise _bad(f"iFacialMocap field {f[:40]!r} is neither a blendshape nor a pose")
            try:
                v = float(value)
            except ValueError:
                raise _bad(f"iFacialMocap value of {name!r} is not a number: {value[:20]!r}") from None
            if not math.isfinite(v):
                raise _bad(f"iFacialMocap value of {name!r} is not finite")
            canon = canonical_name(name)
            if canon in seen:
                raise _bad(f"iFacialMocap packet repeats {name!r}")
            seen.add(canon)
            if canon in _IFM_INDEX:
                weights[_IFM_INDEX[canon]] = v / 100.0
    if "=head#" not in poses:
        raise _bad("iFacialMocap packet has no head pose (=head#…)")
    if not seen:
        raise _bad("iFacialMocap packet has no blendshapes")
    head = poses["=head#"]
    zero = np.zeros(3)
    return LiveFrame(FACECAP_52, weights, head=ypr_from_degrees(head[:3]), time=arrival, arrival=arrival,
                     eye_left=ypr_from_degrees(poses.get("leftEye#", zero)),
                     eye_right=ypr_from_degrees(poses.get("rightEye#", zero)), head_position=head[3:].copy())


# ------------------------------------------------------------------ Face Cap (messages already parsed)
def quaternion_to_yaw_pitch_roll(q: Sequence[float]) -> np.ndarray:
    """Quaternion ``(x, y, z, w)`` → ``(yaw, pitch, roll)`` radians with ``R = R_y(yaw) R_x(pitch) R_z(roll)``."""
    x, y, z, w = (float(v) for v in q)
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not n > 0 or not math.isfinite(n):
        raise _bad("head quaternion is zero or not finite")
    x, y, z, w = x / n, y / n, z / n, w / n
    r02 = 2 * (x * z + w * y)
    r12 = 2 * (y * z - w * x)
    r22 = 1 - 2 * (x * x + y * y)
    r10 = 2 * (x * y + w * z)
    r11 = 1 - 2 * (x * x + z * z)
    pitch = math.asin(max(-1.0, min(1.0, -r12)))
    return np.array([math.atan2(r02, r22), pitch, math.atan2(r10, r11)])


class FaceCapAssembler:
    """Face Cap's OSC messages → frames (one per OSC bundle, or per completed ``/W`` sweep).

    Face Cap sends ``/W index value`` for each blendshape (index into :data:`~.frames.FACECAP_52`),
    ``/HR x y z`` head Euler degrees (x pitch, y yaw, z roll) or ``/HRQ x y z w``, ``/HT x y z`` head
    position and ``/ELR`` / ``/ERR`` eye Euler degrees (x pitch, y yaw).  The assembler keeps the latest
    value of every channel; :meth:`frame` snapshots them.  Not thread-safe: one per receiver thread.
    """

    def __init__(self) -> None:
        self.weights = np.zeros(len(FACECAP_52))
        self.head = np.zeros(3)
        self.position = np.zeros(3)
        self.eye_left = np.zeros(3)
        self.eye_right = np.zeros(3)
        self.sweep_done = False

    def apply(self, address: str, args: Sequence) -> None:
        """Apply one parsed message; unknown addresses are ignored (Face Cap may add some).

        Raises
        ------
        ShapeSpaceError
            ``malformed_packet`` for a known address with the wrong number or type of arguments.
        """
        vals = self._numbers(address, args)
        if address == "/W":
            if len(vals) != 2 or not float(vals[0]).is_integer() or not 0 <= vals[0] < len(FACECAP_52):
                raise _bad(f"Face Cap /W needs an index 0…{len(FACECAP_52) - 1} and a value, got {list(args)[:3]}")
            self.weights[int(vals[0])] = vals[1]
            self.sweep_done = int(vals[0]) == len(FACECAP_52) - 1
        elif address == "/HR":
            self.head = ypr_from_degrees(self._count(address, vals, 3))
        elif address == "/HRQ":
            self.head = quaternion_to_yaw_pitch_roll(self._count(address, vals, 4))
        elif address == "/HT":
            self.position = self._count(address, vals, 3)
        elif address in ("/ELR", "/ERR"):
            eye = eye_ypr_from_degrees(self._count(address, vals, 2))
            if address == "/ELR":
                self.eye_left = eye
            else:
                self.eye_right = eye

    @staticmethod
    def _numbers(address: str, args: Sequence) -> np.ndarray:
        if address not in ("/W", "/HR", "/HRQ", "/HT", "/ELR", "/ERR"):
            return np.zeros(0)
        if any(isinstance(a, bool) or not isinstance(a, (int, float)) for a in args):
            raise _bad(f"Face Cap {address} has non-numeric arguments")
        vals = np.array(args, dtype=np.float64)
        if not np.isfinite(vals).all():
            raise _bad(f"Face Cap {address} has non-finite arguments")
        return vals

    @staticmethod
    def _count(address: str, vals: np.ndarray, n: int) -> np.ndarray:
        if vals.size != n:
            raise _bad(f"Face Cap {address} needs {n} numbers, got {vals.size}")
        return vals

    def frame(self, time: float, arrival: float) -> LiveFrame:
        """A snapshot of the current values as a frame at source ``time``."""
        self.sweep_done = False
        return LiveFrame(FACECAP_52, self.weights.copy(), head=self.head.copy(), eye_left=self.eye_left.copy(),
                         eye_right=self.eye_right.copy(), time=time, arrival=arrival,
                         head_position=self.position.copy())
