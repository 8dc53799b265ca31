"""stop_on_signals: a signal sets the event from a watcher thread, even while the main thread is waiting on
that very event (where a Python-level handler calling ``stop.set()`` could deadlock it)."""

from __future__ import annotations

import os
import signal
import threading

from shared.stopsignals import stop_on_signals


def _send_soon(sig: signal.Signals, ready: threading.Event) -> threading.Thread:
    def send() -> None:
        ready.wait(10)
        os.kill(os.getpid(), sig)

    t = threading.Thread(target=send, daemon=True)
    t.start()
    return t


def test_a_signal_sets_the_event_while_the_main_thread_waits_on_it() -> None:
    stop = threading.Event()
    restore = stop_on_signals(stop, (signal.SIGUSR1,))
    try:
        ready = threading.Event()
        sender = _send_soon(signal.SIGUSR1, ready)
        ready.set()
        # the main thread sits in stop.wait() (holding and releasing the event's lock) when the signal lands
        got = False
        for _ in range(200):
            if stop.wait(0.05):
                got = True
                break
        sender.join(10)
        assert got
    finally:
        restore()


def test_other_signals_do_not_set_it_and_restore_puts_the_handler_back() -> None:
    before = signal.getsignal(signal.SIGUSR2)
    stop = threading.Event()
    restore = stop_on_signals(stop, (signal.SIGUSR1,))
    restore()
    assert signal.getsignal(signal.SIGUSR1) is not None
    assert signal.getsignal(signal.SIGUSR2) is before
    assert not stop.is_set()
    # after restore the watcher is gone: a signal handled by a handler of our own no longer sets the event
    seen = threading.Event()
    old = signal.signal(signal.SIGUSR1, lambda *_: seen.set())
    try:
        os.kill(os.getpid(), signal.SIGUSR1)
        assert seen.wait(5)
        assert not stop.is_set()  # the wake-up descriptor is no longer ours: nothing can reach the watcher
    finally:
        signal.signal(signal.SIGUSR1, old)


def test_it_keeps_working_when_the_caller_drops_the_restore_function() -> None:
    import gc

    before_fd = signal.set_wakeup_fd(-1)
    signal.set_wakeup_fd(before_fd)
    previous = signal.getsignal(signal.SIGUSR1)
    stop = threading.Event()
    stop_on_signals(stop, (signal.SIGUSR1,))  # the restore function is dropped at once, as the CLIs do
    gc.collect()
    try:
        os.kill(os.getpid(), signal.SIGUSR1)
        assert stop.wait(10)
    finally:
        signal.set_wakeup_fd(before_fd)
        signal.signal(signal.SIGUSR1, previous)
