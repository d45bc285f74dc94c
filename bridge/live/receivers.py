"""Receiver threads: one background thread per source that only turns datagrams into frames.

The thread never touches Blender: it reads its UDP socket (short timeouts, so
Stop is prompt), decodes each datagram with a pure decoder and hands the frames
to a :class:`Mailbox`, which the main thread drains from its timer.  Frames
keep their order; duplicated or reordered frames (a time not after the newest)
are counted and dropped, gaps in a source's frame counter are counted as
dropped frames, and a bounded queue keeps a stalled main thread from growing
memory.
"""
from __future__ import annotations

import errno
import socket
import threading
import time
from collections import deque
from collections.abc import Callable

from ...core.errors import ErrorCode
from ...core.live import MAX_DATAGRAM, LiveFrame, decode_ifacialmocap, decode_llf
from ...core.result import ShapeSpaceError

__all__ = ["Mailbox", "UdpReceiver", "llf_decoder", "ifacialmocap_decoder", "RESTART_SECONDS"]

#: A frame this much older than the newest is a restarted source clock, not a reordered packet.
RESTART_SECONDS = 1.0
#: Socket read timeout: how long Stop may wait for the thread.
POLL_SECONDS = 0.05


class Mailbox:
    """Thread-safe hand-over of decoded frames from a receiver thread to the main thread, with counters.

    ``counts`` (read with :meth:`snapshot`): ``datagrams`` received, ``frames`` accepted, ``malformed``,
    ``implausible`` (decoded, but a weight or angle lies beyond the plausibility limits: refused), ``no_face``
    packets, ``late`` (duplicated or reordered frames dropped), ``dropped`` (gaps in the source's frame counter),
    ``overflow`` (frames discarded because the main thread fell behind by ``capacity`` frames), ``restarts``
    (the source's clock jumped back).
    """

    def __init__(self, capacity: int = 2048) -> None:
        self._lock = threading.Lock()
        self._frames = deque()
        self.capacity = capacity
        self._counts = dict(datagrams=0, frames=0, malformed=0, implausible=0, no_face=0, late=0, dropped=0,
                            overflow=0, restarts=0)
        self._last_error = ""
        self._last_arrival = None
        self._arrivals = deque(maxlen=600)
        self._last_time = None
        self._last_frame = None

    def note_datagram(self, arrival: float) -> None:
        with self._lock:
            self._counts["datagrams"] += 1
            self._last_arrival = arrival
            self._arrivals.append(arrival)

    def note_malformed(self, message: str, implausible: bool = False) -> None:
        """Count a refused datagram (``implausible``: it decoded, but a value is absurd) and keep its reason."""
        with self._lock:
            self._counts["implausible" if implausible else "malformed"] += 1
            self._last_error = message

    def note_no_face(self) -> None:
        with self._lock:
            self._counts["no_face"] += 1

    def put(self, frame: LiveFrame) -> bool:
        """Queue ``frame`` unless it is not newer than the last one; returns whether it was queued."""
        with self._lock:
            if self._last_time is not None and frame.time <= self._last_time:
                if frame.time > self._last_time - RESTART_SECONDS:
                    self._counts["late"] += 1
                    return False
                self._counts["restarts"] += 1
                self._last_frame = None
            elif frame.frame is not None and self._last_frame is not None and frame.rate:
                gap = frame.frame - self._last_frame - 1
                if 0 < gap <= 2 * frame.rate:                   # a longer jump is a new take, not losses
                    self._counts["dropped"] += gap
            self._last_time = frame.time
            self._last_frame = frame.frame
            self._counts["frames"] += 1
            self._frames.append(frame)
            if len(self._frames) > self.capacity:
                self._frames.popleft()
                self._counts["overflow"] += 1
            return True

    def drain(self) -> list:
        """Every queued frame, oldest first (the queue is emptied)."""
        with self._lock:
            out = list(self._frames)
            self._frames.clear()
        return out

    def snapshot(self, now: float | None = None) -> dict:
        """Counters plus ``rate`` (datagrams per second over the last second), ``age`` (seconds since the
        last datagram, None before the first) and ``error`` (the last refused packet's reason)."""
        now = time.monotonic() if now is None else now
        with self._lock:
            out = dict(self._counts)
            recent = [a for a in self._arrivals if a > now - 1.0]
            out["rate"] = float(len(recent))
            out["age"] = None if self._last_arrival is None else max(now - self._last_arrival, 0.0)
            out["error"] = self._last_error
        return out


def llf_decoder() -> Callable:
    """Live Link Face v6: one frame per datagram (``None`` for a "no face" packet)."""
    def decode(data: bytes, arrival: float) -> list:
        return [decode_llf(data, arrival)]
    return decode


def ifacialmocap_decoder() -> Callable:
    """iFacialMocap text: one frame per datagram, timed by arrival."""
    def decode(data: bytes, arrival: float) -> list:
        return [decode_ifacialmocap(data, arrival)]
    return decode


class UdpReceiver:
    """A bound UDP socket and the thread that decodes what arrives on it into a :class:`Mailbox`.

    The socket is bound in the constructor (on the calling thread), so a port already in use is a clear
    error before anything starts.  :meth:`stop` closes the socket and joins the thread.
    """

    def __init__(self, host: str, port: int, decode: Callable, mailbox: Mailbox, label: str) -> None:
        self.host, self.port, self.label = host, int(port), label
        self.decode, self.mailbox = decode, mailbox
        self._stop = threading.Event()
        self._thread = None
        if not 0 < self.port < 65536:
            raise ShapeSpaceError(f"UDP port {port} is not a port number (1–65535)", ErrorCode.RANGE)
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
            sock.bind((host, self.port))
        except OSError as exc:
            sock.close()
            if exc.errno in (errno.EADDRINUSE, getattr(errno, "WSAEADDRINUSE", -1)):
                raise ShapeSpaceError(f"UDP port {self.port} on {host} is already in use (another receiver or "
                                      "program): stop it or choose another port", ErrorCode.PORT_IN_USE) from None
            raise ShapeSpaceError(f"cannot listen on UDP {host}:{self.port}: {exc.strerror or exc}",
                                  ErrorCode.NETWORK) from None
        sock.settimeout(POLL_SECONDS)
        self.sock = sock

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name=f"ShapeSpace live {self.label}", daemon=True)
        self._thread.start()

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data, _ = self.sock.recvfrom(MAX_DATAGRAM)
            except socket.timeout:
                continue
            except OSError as exc:
                if not self._stop.is_set():
                    self.mailbox.note_malformed(f"socket error: {exc}")
                break
            arrival = time.monotonic()
            self.mailbox.note_datagram(arrival)
            try:
                frames = self.decode(data, arrival)
            except ShapeSpaceError as exc:
                self.mailbox.note_malformed(str(exc), implausible=exc.code == ErrorCode.RANGE)
                continue
            except Exception as exc:  # noqa: BLE001 — a decoder bug must not end the receiver
                self.mailbox.note_malformed(f"{type(exc).__name__}: {exc}")
                continue
            for frame in frames:
                if frame is None:
                    self.mailbox.note_no_face()
                else:
                    self.mailbox.put(frame)

    def stop(self, timeout: float = 2.0) -> bool:
        """Stop the thread, join it (at most ``timeout`` s) and close the socket; True when it ended."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout)
        self.sock.close()
        return not self.alive
