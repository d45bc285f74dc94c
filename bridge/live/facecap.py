"""Face Cap's OSC stream, parsed by python-osc (shipped with the extension as a wheel).

Each datagram is an OSC bundle (one frame: every message in it, timed by the
bundle's time tag unless it is "immediately") or a single message (a frame is
complete when the last blendshape, ``/W 51``, arrives; timed by arrival).  A
bundle's framing is checked whole first (:func:`core.live.osc_bundle_messages`:
sizes, lengths, bounded nesting — python-osc would read a truncated message
with zero padding and recurse without bound), then python-osc parses each
message and :class:`core.live.FaceCapAssembler` applies them all or none.
"""
from __future__ import annotations

from collections.abc import Callable

from ...core.errors import ErrorCode
from ...core.live import FaceCapAssembler, check_osc_message, osc_bundle_messages
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


def _time_tag(tag: int) -> float | None:
    """A bundle's 64-bit time tag in seconds since 1970, exactly from its fixed-point value (python-osc's
    float conversion adds the NTP era offset first and keeps only ~0.2 µs); None for "immediately"."""
    if tag == 1:
        return None
    return float((tag >> 32) - NTP_UNIX_OFFSET) + (tag & 0xFFFFFFFF) / 2.0 ** 32


def facecap_decoder() -> Callable:
    """A decoder ``(datagram, arrival) → [frames]`` with its own :class:`~core.live.FaceCapAssembler` state
    (one per receiver thread)."""
    osc_bundle, osc_message, _ = _osc()
    assembler = FaceCapAssembler()

    def decode(data: bytes, arrival: float) -> list:
        try:
            if osc_bundle.OscBundle.dgram_is_bundle(data):
                tag, parts = osc_bundle_messages(data)
                messages = [osc_message.OscMessage(part) for part in parts]
                assembler.apply_bundle([(msg.address, msg.params) for msg in messages])
                stamp = _time_tag(tag)
                return [assembler.frame(arrival if stamp is None else stamp, arrival)]
            if osc_message.OscMessage.dgram_is_message(data):
                check_osc_message(data)
                msg = osc_message.OscMessage(data)
                assembler.apply(msg.address, msg.params)
                return [assembler.frame(arrival, arrival)] if assembler.sweep_done else []
        except (osc_bundle.ParseError, osc_message.ParseError) as exc:
            raise ShapeSpaceError(f"Face Cap datagram is not OSC: {exc}", ErrorCode.MALFORMED_PACKET) from None
        raise ShapeSpaceError("Face Cap datagram is neither an OSC message nor a bundle", ErrorCode.MALFORMED_PACKET)
    return decode
