"""Replay a Live Link Face CSV recording as a live stream (Live Link Face v6, Face Cap OSC or iFacialMocap).

    python tools/live_replay.py CSV [--protocol llf|facecap|ifacialmocap] [--host 127.0.0.1] [--port N]
                                    [--rate 60] [--loops 1]

Plays the recording into ShapeSpace's Live receiver from another process, paced at ``--rate`` packets per
second, the way the phone would send it.  The CSV's values and timecodes are carried exactly: Live Link Face
packets hold the timecode's frame and sub-frame, Face Cap bundles are time-tagged with the same seconds.
Loops continue the timecode (so a 60 s replay of a 5 s take is one continuous stream).  Sends to the
loopback address unless told otherwise.
"""
from __future__ import annotations

import argparse
import csv
import math
import os
import socket
import struct
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)

from core.live import FACECAP_52, LLF_CURVES, encode_ifacialmocap, encode_llf  # noqa: E402
from core.names import canonical_name  # noqa: E402

PORTS = {"llf": 11111, "facecap": 8080, "ifacialmocap": 49983}
NTP_UNIX_OFFSET = 2208988800


def read_rows(path: str) -> tuple:
    """The recording's rows: ``(frame numbers (60 fps timecode), sub-frames, values (f, 61) in LLF_CURVES order)``."""
    with open(path, encoding="utf-8-sig", newline="") as fh:
        rows = [r for r in csv.reader(fh) if any(c.strip() for c in r)]
    header = [h.strip() for h in rows[0]]
    cols = [header.index(n) for n in LLF_CURVES]
    frames, subs, values = [], [], []
    for r in rows[1:]:
        h, m, s, ff = r[header.index("Timecode")].strip().split(":")
        whole, _, frac = ff.partition(".")
        frames.append(((int(h) * 60 + int(m)) * 60 + int(s)) * 60 + int(whole))
        subs.append(float("0." + frac) if frac else 0.0)
        values.append([float(r[j]) if r[j].strip() else 0.0 for j in cols])
    return frames, subs, values


def llf_packets(path: str, loops: int = 1, subject: str = "Replay") -> list:
    """``[(seconds, datagram)]``: one Live Link Face v6 packet per row."""
    frames, subs, values = read_rows(path)
    span = frames[-1] - frames[0] + 1
    return [((f + loop * span + sub) / 60.0, encode_llf(v, f + loop * span, sub, 60, subject=subject))
            for loop in range(loops) for f, sub, v in zip(frames, subs, values)]


def _facecap_weights(values: list) -> list:
    by_name = {canonical_name(n): v for n, v in zip(LLF_CURVES[:52], values)}
    return [by_name[canonical_name(n)] for n in FACECAP_52]


def _exact_time_tag(dgram: bytes, frame: int, sub: float) -> bytes:
    """The bundle with its time tag set to ``(frame + sub) / 60`` s exactly in OSC's 32.32 fixed point
    (python-osc's float conversion adds the NTP era offset first and keeps only ~0.2 µs)."""
    whole, rem = divmod(frame, 60)
    frac = (rem + sub) / 60.0
    tag = ((whole + NTP_UNIX_OFFSET) << 32) + int(round(frac * 2 ** 32))
    return dgram[:8] + struct.pack(">Q", tag) + dgram[16:]


def facecap_packets(path: str, loops: int = 1) -> list:
    """``[(seconds, datagram)]``: one Face Cap OSC bundle per row, time-tagged with the row's seconds."""
    from pythonosc import osc_bundle_builder, osc_message_builder

    def message(address, *args):
        b = osc_message_builder.OscMessageBuilder(address)
        for a in args:
            b.add_arg(a)
        return b.build()

    frames, subs, values = read_rows(path)
    span = frames[-1] - frames[0] + 1
    out = []
    for loop in range(loops):
        for f, sub, v in zip(frames, subs, values):
            t = (f + loop * span + sub) / 60.0
            yaw, pitch, roll, ly, lp, _, ry, rp, _ = (math.degrees(x) for x in v[52:])
            bundle = osc_bundle_builder.OscBundleBuilder(t)
            bundle.add_content(message("/HT", 0.0, 0.0, 0.0))
            bundle.add_content(message("/HR", pitch, yaw, roll))
            bundle.add_content(message("/ELR", lp, ly))
            bundle.add_content(message("/ERR", rp, ry))
            for i, w in enumerate(_facecap_weights(v)):
                bundle.add_content(message("/W", i, float(w)))
            out.append((t, _exact_time_tag(bundle.build().dgram, f + loop * span, sub)))
    return out


def ifacialmocap_packets(path: str, loops: int = 1) -> list:
    """``[(seconds, datagram)]``: one iFacialMocap text datagram per row (it carries no timecode)."""
    frames, subs, values = read_rows(path)
    span = frames[-1] - frames[0] + 1
    out = []
    for loop in range(loops):
        for f, sub, v in zip(frames, subs, values):
            yaw, pitch, roll, ly, lp, lr, ry, rp, rr = (math.degrees(x) for x in v[52:])
            out.append(((f + loop * span + sub) / 60.0,
                        encode_ifacialmocap(_facecap_weights(v), (pitch, yaw, roll), (0, 0, 0), (rp, ry, rr),
                                            (lp, ly, lr))))
    return out


PROTOCOLS = {"llf": llf_packets, "facecap": facecap_packets, "ifacialmocap": ifacialmocap_packets}


def send(packets: list, host: str = "127.0.0.1", port: int = 11111, rate: float = 60.0,
         deadline: float | None = None, stop=None) -> int:
    """Send ``[(seconds, datagram)]`` at ``rate`` per second (absolute schedule: no drift); returns how many
    were sent (fewer if ``deadline``, a ``time.monotonic()`` value, passes first, or ``stop``, a
    ``threading.Event``, is set)."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        start = time.monotonic()
        for k, (_, data) in enumerate(packets):
            due = start + k / rate
            now = time.monotonic()
            if (deadline is not None and now > deadline) or (stop is not None and stop.is_set()):
                return k
            if due > now:
                time.sleep(due - now)
            sock.sendto(data, (host, port))
        return len(packets)
    finally:
        sock.close()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("csv")
    ap.add_argument("--protocol", choices=sorted(PROTOCOLS), default="llf")
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--port", type=int, default=None)
    ap.add_argument("--rate", type=float, default=60.0)
    ap.add_argument("--loops", type=int, default=1)
    args = ap.parse_args(argv)
    packets = PROTOCOLS[args.protocol](args.csv, args.loops)
    port = args.port or PORTS[args.protocol]
    sent = send(packets, args.host, port, args.rate)
    print(f"live_replay: sent {sent} {args.protocol} packets to {args.host}:{port}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
