"""Face Cap's OSC stream, parsed by python-osc (shipped with the extension as a wheel).

Each datagram is an OSC bundle (one frame: every message in it, timed by the
bundle's time tag unless it is "immediately") or a single message (a frame is
complete when the last blendshape, ``/W 51``, arrives; timed by arrival).  The
messages themselves are interpreted by :class:`core.live.FaceCapAssembler`.
"""
from __future__ import annotations

import struct
from collections.abc import Callable

from ...core.errors import ErrorCode
from ...core.live import FaceCapAssembler
from ...core.result import ShapeSpaceError

__all__ = ["facecap_decoder", "osc_available", "NTP_UNIX_OFFSET"]

#: Seconds from the NTP epoch (1900) to the Unix epoch (1970).
NTP_UNIX_OFFSET = 2208988800


def _osc():
    try:
        from pythonosc import osc_bundle, osc_message
        from pythonosc.parsing import osc_types
    except ImportError:
        raise ShapeSpaceError("Face Cap needs the python-osc library, which ShapeSpace ships as a wheel: reinstall "
                              "the extension (or `pip install python-osc` for a development checkout)",
                              ErrorCode.MISSING_LIBRARY) from None
    return osc_bundle, osc_message, osc_types


def osc_available() -> bool:
    """Whether python-osc can be imported."""
    try:
        _osc()
    except ShapeSpaceError:
        return False
    return True


def _time_tag(bundle: bytes) -> float | None:
    """The bundle's time tag in seconds since 1970, read exactly from its fixed-point header (python-osc's
    float conversion adds the NTP era offset first and keeps only ~0.2 µs); None for "immediately"."""
    (tag,) = struct.unpack_from(">Q", bundle, 8)
    if tag == 1:
        return None
    return float((tag >> 32) - NTP_UNIX_OFFSET) + (tag & 0xFFFFFFFF) / 2.0 ** 32


def facecap_decoder() -> Callable:
    """A decoder ``(datagram, arrival) → [frames]`` with its own :class:`~core.live.FaceCapAssembler` state
    (one per receiver thread)."""
    osc_bundle, osc_message, _ = _osc()
    assembler = FaceCapAssembler()

    def messages(bundle) -> list:
        out = []
        for content in bundle:
            out += messages(content) if isinstance(content, osc_bundle.OscBundle) else [content]
        return out

    def decode(data: bytes, arrival: float) -> list:
        try:
            if osc_bundle.OscBundle.dgram_is_bundle(data):
                bundle = osc_bundle.OscBundle(data)
                for msg in messages(bundle):
                    assembler.apply(msg.address, msg.params)
                stamp = _time_tag(data)
                return [assembler.frame(arrival if stamp is None else stamp, arrival)]
            if osc_message.OscMessage.dgram_is_message(data):
                msg = osc_message.OscMessage(data)
                assembler.apply(msg.address, msg.params)
                return [assembler.frame(arrival, arrival)] if assembler.sweep_done else []
        except (osc_bundle.ParseError, osc_message.ParseError) as exc:
            raise ShapeSpaceError(f"Face Cap datagram is not OSC: {exc}", ErrorCode.MALFORMED_PACKET) from None
        raise ShapeSpaceError("Face Cap datagram is neither an OSC message nor a bundle", ErrorCode.MALFORMED_PACKET)
    return decode
