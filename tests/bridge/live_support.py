"""Helpers for the live-capture tests: free loopback ports, a sender thread, the timer driven as Blender would.

The ``bpy`` module has no event loop, so ``bpy.app.timers`` never fire on their own: :func:`drive` calls the
registered timer function the way Blender's loop does (every few milliseconds) until a condition holds or a
deadline passes.  Every network call goes to 127.0.0.1 and every loop is bounded in time.
"""
import socket
import threading
import time

import bpy

import live_replay  # tools/live_replay.py
from blender_support import SS  # noqa: F401  (the add-on is loaded)
from shapespace.bridge.live import session

CSV = live_replay.os.path.join(live_replay.ROOT, "assets", "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")
HOST = "127.0.0.1"


def free_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind((HOST, 0))
    port = s.getsockname()[1]
    s.close()
    return port


def configure(target, source="LLF", method="COPY", **settings):
    """Scene live settings for ``target`` on a fresh loopback port; returns the port."""
    st = bpy.context.scene.shapespace_live
    st.source = source
    st.address = HOST
    st.port = free_port()
    st.target = target
    st.method = method
    for k, v in settings.items():
        setattr(st, k, v)
    return st.port


def sender(packets, port, rate=60.0, seconds=30.0):
    """Send ``[(t, datagram)]`` from a thread at ``rate``; returns the started thread (ends by itself after
    ``seconds``, or at once after :func:`halt`)."""
    stop = threading.Event()
    th = threading.Thread(target=live_replay.send, args=(packets, HOST, port, rate, time.monotonic() + seconds,
                                                         stop), daemon=True)
    th.stop = stop
    th.start()
    return th


def halt(th) -> None:
    """Stop a :func:`sender` thread now and wait for it."""
    th.stop.set()
    th.join(10)
    assert not th.is_alive()


def raw_sender(datagrams, port):
    """Send raw datagrams at once (malformed packets and the like)."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for d in datagrams:
            s.sendto(d, (HOST, port))
    finally:
        s.close()


def drive(until, seconds=20.0, interval=0.002):
    """Run the live timer as Blender's event loop would until ``until()`` is true; False on the deadline."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if bpy.app.timers.is_registered(session._timer):
            session.tick()
        if until():
            return True
        time.sleep(interval)
    return False


def frames_received() -> int:
    s = session.RUNTIME.session
    return s.mailbox.snapshot()["frames"] if s is not None else -1


def replay_and_drain(packets, port, rate=60.0, seconds=30.0):
    """Send ``packets`` and drive the timer until every one was received and applied."""
    th = sender(packets, port, rate, seconds)
    ok = drive(lambda: not th.is_alive() and frames_received() >= len(packets), seconds)
    session.tick()                              # applies what arrived since the last tick
    th.join(5)
    return ok
