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
- **Face Cap**'s OSC datagrams: :func:`osc_bundle_messages` checks a bundle's framing whole (every element's
  size, every message's length against its type tags, bounded nesting) and splits it into messages, which
  python-osc parses in the bridge; :class:`FaceCapAssembler` turns the parsed messages (``/W`` index value,
  ``/HR`` or ``/HRQ``, ``/HT``, ``/ELR``, ``/ERR``) into frames, a bundle only once all of it is valid.

Every decoder validates everything and raises :class:`~core.result.ShapeSpaceError` (code
``malformed_packet``) with a one-line reason; a frame with finite but absurd values (a weight beyond
±:data:`~core.blendshape.MAX_ABS_WEIGHT`, an angle beyond ±:data:`~.frames.MAX_ABS_ANGLE`) is refused
with code ``range`` (:func:`~.frames.implausible_channel`).  The receiver counts those and carries on.
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
from .frames import FACECAP_52, LLF_BLENDSHAPES, LLF_CURVES, LiveFrame, implausible_channel

__all__ = ["LLF_PORT", "LLF_VERSION", "IFM_PORT", "FACECAP_PORT", "MAX_DATAGRAM", "MAX_OSC_DEPTH", "encode_llf",
           "decode_llf", "encode_ifacialmocap", "decode_ifacialmocap", "FaceCapAssembler",
           "quaternion_to_yaw_pitch_roll", "osc_bundle_messages", "check_osc_message", "ypr_from_degrees",
           "eye_ypr_from_degrees"]

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


def _plausible(frame: LiveFrame, source: str) -> LiveFrame:
    """``frame``, or a ``range`` error naming its first absurd channel (:func:`~.frames.implausible_channel`)."""
    why = implausible_channel(frame.names, frame.vector())
    if why:
        raise ShapeSpaceError(f"{source} frame refused: {why}", ErrorCode.RANGE)
    return frame


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
        trailing bytes, non-finite values or a non-positive rate; ``range``: an absurd weight or angle.
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
    return _plausible(LiveFrame(LLF_BLENDSHAPES, values[:52], head=values[52:55].copy(),
                                eye_left=values[55:58].copy(), eye_right=values[58:61].copy(),
                                time=(frame + subframe) / rate, frame=int(frame), rate=rate, arrival=arrival,
                                subject=subject), "Live Link Face")


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
        duplicates, too many fields; ``range``: an absurd weight or angle.
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
    return _plausible(LiveFrame(FACECAP_52, weights, head=ypr_from_degrees(head[:3]), time=arrival, arrival=arrival,
                                eye_left=ypr_from_degrees(poses.get("leftEye#", zero)),
                                eye_right=ypr_from_degrees(poses.get("rightEye#", zero)),
                                head_position=head[3:].copy()), "iFacialMocap")


# ------------------------------------------------------------------ OSC framing (Face Cap)
#: Deepest nesting of OSC bundles accepted (Face Cap nests none): deeper is refused, never recursed into.
MAX_OSC_DEPTH = 8
_OSC_BUNDLE = b"#bundle\0"
#: Bytes of each OSC argument type of fixed size (True, False, Nil, Impulse and array brackets carry none).
_OSC_FIXED = {"i": 4, "f": 4, "c": 4, "r": 4, "m": 4, "h": 8, "t": 8, "d": 8, "T": 0, "F": 0, "N": 0, "I": 0,
              "[": 0, "]": 0}


def _osc_string_end(data: bytes, at: int, what: str) -> int:
    """Where the NUL-terminated, 4-byte padded OSC string starting at ``at`` ends."""
    nul = data.find(b"\0", at)
    if nul < 0:
        raise _bad(f"OSC {what} is not terminated ({len(data)} bytes: truncated)")
    end = (nul // 4 + 1) * 4
    if end > len(data) or data[nul:end].strip(b"\0"):
        raise _bad(f"OSC {what} is not padded to 4 bytes ({len(data)} bytes: truncated)")
    return end


def check_osc_message(data: bytes) -> None:
    """Refuse an OSC message whose length is not exactly what its address, type tags and arguments take.

    (python-osc pads a short float with zeros and ignores trailing bytes: a truncated message would read.)

    Raises
    ------
    ShapeSpaceError
        ``malformed_packet`` naming the message's address and what is wrong.
    """
    if not data.startswith(b"/"):
        raise _bad("OSC message does not start with an address ('/…')")
    at = _osc_string_end(data, 0, "address")
    address = data[:data.index(b"\0")].decode("ascii", errors="replace")[:40]
    if at >= len(data) or data[at:at + 1] != b",":
        raise _bad(f"OSC message {address} has no type tags (truncated)")
    end = _osc_string_end(data, at, f"type tags of {address}")
    tags = data[at + 1:data.index(b"\0", at)].decode("ascii", errors="replace")
    at = end
    for tag in tags:
        if tag in _OSC_FIXED:
            at += _OSC_FIXED[tag]
        elif tag in "sS":
            if at >= len(data):
                raise _bad(f"OSC message {address} is truncated before a string argument ({len(data)} bytes)")
            at = _osc_string_end(data, at, f"string argument of {address}")
        elif tag == "b":
            size = struct.unpack_from(">i", data, at)[0] if at + 4 <= len(data) else -1
            if size < 0:
                raise _bad(f"OSC message {address} is truncated in a blob ({len(data)} bytes)")
            at += 4 + (size + 3) // 4 * 4
        else:
            raise _bad(f"OSC message {address} has an unknown argument type {tag!r}")
        if at > len(data):
            raise _bad(f"OSC message {address} is truncated: its arguments ({tags}) need more than its "
                       f"{len(data)} bytes")
    if at != len(data):
        raise _bad(f"OSC message {address} has {len(data) - at} bytes after its arguments ({tags})")


def osc_bundle_messages(data: bytes) -> tuple:
    """An OSC bundle's time tag and its messages, the framing checked whole before anything is used.

    Every element's size must be a positive multiple of 4 that the datagram holds, the elements must fill the
    bundle exactly, every message's length must match its type tags (:func:`check_osc_message`), and bundles
    may nest at most :data:`MAX_OSC_DEPTH` deep (walked without recursion).

    Returns
    -------
    tag : int
        The outer bundle's 64-bit time tag (1: "immediately").
    messages : list of bytes
        Every message datagram, in order (nested bundles flattened).

    Raises
    ------
    ShapeSpaceError
        ``malformed_packet`` with the reason (truncated, impossible size, nested too deep, …).
    """
    if not data.startswith(_OSC_BUNDLE) or len(data) < 16:
        raise _bad(f"OSC bundle header truncated ({len(data)} bytes)")
    (tag,) = struct.unpack_from(">Q", data, 8)
    messages = []
    stack = [(16, len(data), 1)]                 # (next element, end of its bundle, depth)
    while stack:
        at, end, depth = stack.pop()
        if at == end:
            continue
        if at + 4 > end:
            raise _bad(f"OSC bundle truncated in an element size at byte {at} ({len(data)} bytes)")
        (size,) = struct.unpack_from(">i", data, at)
        if size <= 0 or size % 4 or at + 4 + size > end:
            raise _bad(f"OSC bundle element at byte {at} claims {size} bytes where {end - at - 4} remain "
                       "(truncated or damaged)")
        stack.append((at + 4 + size, end, depth))
        body = data[at + 4:at + 4 + size]
        if body.startswith(_OSC_BUNDLE):
            if depth >= MAX_OSC_DEPTH:
                raise _bad(f"OSC bundles nested more than {MAX_OSC_DEPTH} deep (Face Cap nests none)")
            if size < 16:
                raise _bad(f"OSC bundle at byte {at + 4} is truncated in its header")
            stack.append((at + 4 + 16, at + 4 + size, depth + 1))
        else:
            check_osc_message(body)
            messages.append(body)
    return tag, messages


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


_FACECAP_ADDRESSES = ("/W", "/HR", "/HRQ", "/HT", "/ELR", "/ERR")


class FaceCapAssembler:
    """Face Cap's OSC messages → frames (one per OSC bundle, or per completed ``/W`` sweep).

    Face Cap sends ``/W index value`` for each blendshape (index into :data:`~.frames.FACECAP_52`),
    ``/HR x y z`` head Euler degrees (x pitch, y yaw, z roll) or ``/HRQ x y z w``, ``/HT x y z`` head
    position and ``/ELR`` / ``/ERR`` eye Euler degrees (x pitch, y yaw); each bundle carries every
    blendshape once.  The assembler keeps the latest value of every channel; :meth:`frame` snapshots them.
    Messages are validated (and the resulting frame checked for absurd values) before any of them is
    applied: a refused message or bundle leaves the assembler as it was.  Not thread-safe: one per receiver
    thread.
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
            ``malformed_packet`` for a known address with the wrong number or type of arguments, ``range``
            for an absurd value; nothing is applied then.
        """
        update = self._update(address, args)
        self._commit([update] if update else [], "Face Cap message")
        if update and update[0] == "weights":
            self.sweep_done = update[1] == len(FACECAP_52) - 1

    def apply_bundle(self, messages: Sequence) -> None:
        """Apply a bundle's parsed messages ``[(address, args)]`` all together, or none of them.

        Raises
        ------
        ShapeSpaceError
            As :meth:`apply` for any message, or ``malformed_packet`` when the bundle does not carry every
            blendshape exactly once (a truncated bundle); the assembler is left as it was.
        """
        updates = [u for u in (self._update(a, p) for a, p in messages) if u]
        indices = [u[1] for u in updates if u[0] == "weights"]
        if len(set(indices)) != len(indices):
            raise _bad("Face Cap bundle repeats a /W index")
        if len(indices) != len(FACECAP_52):
            raise _bad(f"Face Cap bundle carries {len(indices)} of {len(FACECAP_52)} blendshapes (truncated?)")
        self._commit(updates, "Face Cap bundle")

    def _update(self, address: str, args: Sequence) -> tuple | None:
        """One message validated into ``(attribute, index or None, value)`` (None for an unknown address)."""
        vals = self._numbers(address, args)
        if address == "/W":
            if len(vals) != 2 or not float(vals[0]).is_integer() or not 0 <= vals[0] < len(FACECAP_52):
                raise _bad(f"Face Cap /W needs an index 0…{len(FACECAP_52) - 1} and a value, got {list(args)[:3]}")
            return "weights", int(vals[0]), float(vals[1])
        if address == "/HR":
            return "head", None, ypr_from_degrees(self._count(address, vals, 3))
        if address == "/HRQ":
            return "head", None, quaternion_to_yaw_pitch_roll(self._count(address, vals, 4))
        if address == "/HT":
            return "position", None, self._count(address, vals, 3)
        if address in ("/ELR", "/ERR"):
            xy = self._count(address, vals, 2)
            return "eye_left" if address == "/ELR" else "eye_right", None, eye_ypr_from_degrees(xy)
        return None

    def _commit(self, updates: list, what: str) -> None:
        """Apply validated updates to copies, check the frame they make, then keep them."""
        state = {k: getattr(self, k).copy() for k in ("weights", "head", "position", "eye_left", "eye_right")}
        for attr, index, value in updates:
            if index is None:
                state[attr] = np.asarray(value, dtype=np.float64)
            else:
                state[attr][index] = value
        vector = np.concatenate([state["weights"], state["head"], state["eye_left"], state["eye_right"]])
        why = implausible_channel(FACECAP_52, vector)
        if why:
            raise ShapeSpaceError(f"{what} refused: {why}", ErrorCode.RANGE)
        for k, v in state.items():
            setattr(self, k, v)

    @staticmethod
    def _numbers(address: str, args: Sequence) -> np.ndarray:
        if address not in _FACECAP_ADDRESSES:
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
