"""Tools of the hostile-input suite (docs/reliability.md): a file-open watch, a loopback listener that counts
connections, a memory probe, byte/text mutations for fuzzing and the fast/soak example counts.

Everything here is real: the watch is Linux inotify (kernel events for every open or read of the secret
file, whoever does it), the listener a TCP socket on 127.0.0.1 (every connection attempt that completes is
counted, accepted in a thread or still queued in the backlog).
"""

from __future__ import annotations

import ctypes
import errno
import os
import socket
import struct
import sys
import threading
import tracemalloc
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any, TypeVar

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

__all__ = [
    "HOSTILE_TOKENS",
    "SOAK_ENV",
    "FileWatch",
    "Listener",
    "assert_only",
    "fast_examples",
    "mutated_bytes",
    "mutated_text",
    "peak_python_bytes",
    "run_fuzz",
    "soak_examples",
]

T = TypeVar("T")

#: Environment variable: hypothesis examples per fuzz target in the soak runs (``make soak``).
SOAK_ENV = "LINEMAP_SOAK_FUZZ_EXAMPLES"
#: Environment variable: examples per fuzz target in the fast part (``make test``).
FAST_ENV = "LINEMAP_FUZZ_EXAMPLES"


def fast_examples(default: int = 300) -> int:
    """Examples per fuzz target in the fast part (``LINEMAP_FUZZ_EXAMPLES`` overrides ``default``)."""
    return int(os.environ.get(FAST_ENV, default))


def soak_examples(default: int = 1000) -> int:
    """Examples per fuzz target in the soak part (``LINEMAP_SOAK_FUZZ_EXAMPLES`` overrides ``default``)."""
    return int(os.environ.get(SOAK_ENV, default))


def run_fuzz(check: Callable[[T], None], strategy: st.SearchStrategy[T], examples: int) -> None:
    """Run ``check`` on ``examples`` inputs drawn from ``strategy`` (hypothesis: shrinks a failure to a
    minimal input and replays it from its example database next time). No deadline: the machine is shared."""

    @settings(
        max_examples=examples,
        deadline=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much],
    )
    @given(strategy)
    def fuzz(value: T) -> None:
        check(value)

    fuzz()


def assert_only(allowed: tuple[type[BaseException], ...], call: Callable[[], object]) -> BaseException | None:
    """Run ``call``; return the error it raised if it is one of ``allowed`` (with a non-empty message),
    ``None`` if it returned; any other exception fails the test, showing its type and traceback."""
    caught: BaseException | None = None
    try:
        call()
    except allowed as exc:
        caught = exc
    except Exception as exc:  # the finding: a foreign exception type escaped the parser
        names = ", ".join(a.__name__ for a in allowed)
        what = f"{type(exc).__name__} escaped (only {names} may): {describe(exc, 300)}"
        raise AssertionError(what) from exc
    if caught is not None:
        assert str(caught).strip(), f"{type(caught).__name__} without a message"
    return caught


def peak_python_bytes(call: Callable[[], object]) -> tuple[int, BaseException | None]:
    """``(peak bytes of Python allocations during call, the exception it raised or None)`` (tracemalloc;
    libxml2's own C allocations are not traced: :func:`rss_growth_kib` covers them)."""
    started = tracemalloc.is_tracing()
    if not started:
        tracemalloc.start()
    tracemalloc.reset_peak()
    before = tracemalloc.get_traced_memory()[0]
    error: BaseException | None = None
    try:
        call()
    except Exception as exc:
        error = exc
    peak = tracemalloc.get_traced_memory()[1] - before
    if not started:
        tracemalloc.stop()
    return peak, error


# --------------------------------------------------------------------------------- file access watch

_IN_ACCESS = 0x00000001
_IN_OPEN = 0x00000020
_IN_NONBLOCK = 0o4000
_IN_CLOEXEC = 0o2000000
_EVENT = struct.Struct("iIII")


class FileWatch:
    """Count opens and reads of one file by anyone (Linux inotify ``IN_OPEN | IN_ACCESS``).

    ``events()`` returns the number of events since the last call. Skips the test off Linux.
    """

    def __init__(self, path: Path) -> None:
        if not sys.platform.startswith("linux"):
            pytest.skip("inotify (Linux) is needed to watch file access")
        libc = ctypes.CDLL(None, use_errno=True)
        self._fd = int(libc.inotify_init1(_IN_NONBLOCK | _IN_CLOEXEC))
        if self._fd < 0:
            raise OSError(ctypes.get_errno(), "inotify_init1 failed")
        wd = int(libc.inotify_add_watch(self._fd, os.fsencode(path), _IN_OPEN | _IN_ACCESS))
        if wd < 0:
            os.close(self._fd)
            raise OSError(ctypes.get_errno(), f"inotify_add_watch({path}) failed")

    def events(self) -> int:
        count = 0
        while True:
            try:
                chunk = os.read(self._fd, 65536)
            except BlockingIOError:
                return count
            pos = 0
            while pos + _EVENT.size <= len(chunk):
                _wd, _mask, _cookie, name_len = _EVENT.unpack_from(chunk, pos)
                pos += _EVENT.size + name_len
                count += 1

    def close(self) -> None:
        os.close(self._fd)

    def __enter__(self) -> FileWatch:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# --------------------------------------------------------------------------------- loopback listener


class Listener:
    """A TCP listener on 127.0.0.1 that accepts and closes every connection and counts them.

    A thread accepts (so a client that waits for an answer is not left hanging); :meth:`count` stops it
    and also drains connections still queued in the backlog, so a connection made before the call is
    always counted, with no timing involved.
    """

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(128)
        self.port: int = self.sock.getsockname()[1]
        self.accepted = 0
        self._wake_r, self._wake_w = socket.socketpair()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def _serve(self) -> None:
        import selectors

        with selectors.DefaultSelector() as sel:
            sel.register(self.sock, selectors.EVENT_READ)
            sel.register(self._wake_r, selectors.EVENT_READ)
            while True:
                for key, _ in sel.select():
                    if key.fileobj is self._wake_r:
                        return
                    conn, _ = self.sock.accept()
                    conn.close()
                    self.accepted += 1

    def count(self) -> int:
        """Connections so far (stops the accepting thread; call once, at the end)."""
        if self._thread.is_alive():
            self._wake_w.send(b"x")
            self._thread.join()
        self.sock.setblocking(False)
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError as exc:
                if exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK):
                    return self.accepted
                raise
            conn.close()
            self.accepted += 1

    def close(self) -> None:
        self.count()
        self.sock.close()
        self._wake_r.close()
        self._wake_w.close()


@contextmanager
def listening() -> Iterator[Listener]:
    listener = Listener()
    try:
        yield listener
    finally:
        listener.close()


# --------------------------------------------------------------------------------------- mutations

#: Tokens that break naive number parsing: non-finite, huge, non-ASCII digits, Python-only spellings.
HOSTILE_TOKENS = (
    "nan", "NaN", "-nan", "inf", "-inf", "Infinity", "1e309", "-1e400", "1e308", "-1.7976931348623157e308",
    "4.9e-324", "99999999999999999999999", "-99999999999999999999999", "0", "-0", "-1", "\u00b2",
    "\u0661\u0662", "\uff11", "0x10", "1_000", "1e", ".", "+", "--1", "\u00a0", "9" * 5000, "\x00",
)  # fmt: skip


@st.composite
def mutated_bytes(draw: st.DrawFn, seed: bytes, max_mutations: int = 4) -> bytes:
    """``seed`` after 1..``max_mutations`` random edits: truncation, byte flips, inserted or deleted runs,
    duplicated runs, hostile tokens spliced in."""
    data = bytearray(seed)
    for _ in range(draw(st.integers(1, max_mutations))):
        kind = draw(st.sampled_from(["truncate", "flip", "insert", "delete", "duplicate", "token", "zero"]))
        n = len(data)
        at = draw(st.integers(0, max(n - 1, 0)))
        if kind == "truncate":
            del data[at:]
        elif kind == "flip" and n:
            data[at] ^= draw(st.integers(1, 255))
        elif kind == "insert":
            data[at:at] = draw(st.binary(min_size=1, max_size=16))
        elif kind == "delete":
            del data[at : at + draw(st.integers(1, 64))]
        elif kind == "duplicate":
            data[at:at] = data[at : at + draw(st.integers(1, 256))]
        elif kind == "token":
            data[at:at] = draw(st.sampled_from(HOSTILE_TOKENS)).encode("utf-8")
        elif kind == "zero" and n:
            stop = min(n, at + draw(st.integers(1, 8)))
            data[at:stop] = bytes(stop - at) if draw(st.booleans()) else b"\xff" * (stop - at)
    return bytes(data)


@st.composite
def mutated_text(draw: st.DrawFn, seed: str, garbage_lines: tuple[str, ...] = ()) -> str:
    """``seed`` (lines of whitespace-separated tokens) with tokens replaced by hostile ones, lines
    dropped, duplicated, cut short or replaced by garbage."""
    lines = seed.splitlines()
    for _ in range(draw(st.integers(1, 4))):
        if not lines:
            lines.append("")
        i = draw(st.integers(0, len(lines) - 1))
        kind = draw(st.sampled_from(["token", "token", "cut", "drop", "dup", "garbage", "text"]))
        tokens = lines[i].split(" ")
        if kind == "token":
            j = draw(st.integers(0, len(tokens) - 1))
            tokens[j] = draw(st.sampled_from(HOSTILE_TOKENS) | st.text(max_size=8))
            lines[i] = " ".join(tokens)
        elif kind == "cut":
            lines[i] = " ".join(tokens[: draw(st.integers(0, len(tokens)))])
        elif kind == "drop":
            del lines[i]
        elif kind == "dup":
            lines.insert(i, lines[i])
        elif kind == "garbage" and garbage_lines:
            lines.insert(i, draw(st.sampled_from(garbage_lines)))
        else:
            lines.insert(i, draw(st.text(max_size=40)))
    return "\n".join(lines) + ("\n" if draw(st.booleans()) else "")


def describe(value: Any, limit: int = 120) -> str:
    """A short repr for assertion messages."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _rss_probe(corpus_path: str) -> None:
    """Child process: parse every document of a pickled corpus, print the RSS high-water growth (KiB)."""
    import json
    import pickle
    import resource

    from shared.control import ControlMessageError, parse_message

    docs = pickle.loads(Path(corpus_path).read_bytes())
    parse_message("<xml><message><mode>online</mode></message></xml>")  # warm up: lxml loaded, caches
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    for doc in docs:
        with suppress(ControlMessageError):
            parse_message(doc)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    sys.stdout.write(json.dumps({"growth_kib": peak - base, "base_kib": base, "documents": len(docs)}))


if __name__ == "__main__":
    if sys.argv[1:2] == ["rss"]:
        _rss_probe(sys.argv[2])
