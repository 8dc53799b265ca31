"""Stopping a program on SIGINT / SIGTERM by setting a :class:`threading.Event`, safely.

Setting the event inside a Python signal handler can deadlock the program for good: the handler runs on
the main thread between two bytecodes, and when the main thread is itself inside ``stop.wait(...)`` at
that moment it holds the event's internal lock, which ``stop.set()`` then waits for forever (seen: an
agent that never exited after Ctrl-C). Here the handler does nothing in Python; the interpreter's C-level
handler writes the signal's number to a socket (:func:`signal.set_wakeup_fd`), and a watcher thread that
blocks on that socket sets the event from outside any lock the main thread holds.
"""

from __future__ import annotations

import signal
import socket
import threading
from collections.abc import Callable, Sequence
from typing import Any

__all__ = ["stop_on_signals"]


def stop_on_signals(
    stop: threading.Event, signals: Sequence[signal.Signals] = (signal.SIGINT, signal.SIGTERM)
) -> Callable[[], None]:
    """From now on each of ``signals`` sets ``stop`` (from a watcher thread). Call from the main thread.
    Returns a function that puts the previous handlers and wake-up descriptor back."""
    reader, writer = socket.socketpair()
    writer.setblocking(False)
    previous_fd = signal.set_wakeup_fd(writer.fileno())
    previous: dict[signal.Signals, Any] = {sig: signal.signal(sig, _ignore) for sig in signals}
    closed = threading.Event()

    def watch() -> None:
        # this thread holds both ends: the caller may drop the returned function (closing the write end
        # would leave the wake-up descriptor pointing at nothing, or at a file opened later)
        _ends = (reader, writer)
        while not closed.is_set():
            try:
                data = reader.recv(64)
            except OSError:
                return
            if not data:
                return
            if any(b in {int(s) for s in signals} for b in data):
                stop.set()

    threading.Thread(target=watch, name="stop-signals", daemon=True).start()

    def restore() -> None:
        signal.set_wakeup_fd(previous_fd)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        closed.set()
        writer.close()
        reader.shutdown(socket.SHUT_RDWR)
        reader.close()

    return restore


def _ignore(signum: int, frame: object) -> None:
    """The Python-level handler: nothing (the watcher thread acts on the wake-up byte)."""
