"""The front end in a process of its own, ahead of the pose graph (offline mapping with loop closure).

Under :class:`~shared.slam.mapper.GraphMapper` the front end (scan matching fused with odometry, tracking
poses only) never reads the graph: it runs in its own frame and the graph reads what it made of each scan
(:class:`Tracked`: the step's result, the returns the pose took, the odometry noise learned so far, the
range noise in force). So offline (``linemap map`` with loop closure) the front end runs in a child
process, scans ahead of the graph, and the graph's work (keyframes, loop searches, iSAM2) runs in this
one beside it: on two cores the two overlap. The graph reads the same :class:`Tracked` it would have read
from a front end in its own process, so the map, the trajectory and the closures are the same bit for bit
(tests/shared/slam/test_frontproc.py).

:class:`FrontEndProcess`: ``send`` scans (a bounded queue: the child runs at most ``ahead`` scans ahead),
``close_input``, and iterate ``results()`` for one :class:`Tracked` per scan, in order. An error of the
front end in the child is raised here as the same :class:`~shared.errors.LinemapError` (or, when it cannot
be carried, as a :class:`FrontEndProcessError` naming it); leaving the ``with`` block stops the child.

Cost: one pickled scan and one pickled result per step through a pipe (tens of microseconds).
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import pickle
import queue
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from types import TracebackType
from typing import Any

from shared.errors import LinemapError
from shared.pipeline import Pipeline, PipelineConfig
from shared.pipeline.odonoise import NoiseScale
from shared.pipeline.pipeline import StepResult
from shared.pipeline.rangenoise import RangeNoise
from shared.slam.errors import SlamError
from shared.types import FloatArray, Pose2D, Scan

__all__ = ["FrontEndProcess", "FrontEndProcessError", "Tracked"]

log = logging.getLogger(__name__)

#: scans sent to the child in one message (fewer, larger messages through the pipe)
BATCH = 8


@dataclass(frozen=True, slots=True)
class Tracked:
    """What the front end made of one scan, as far as the graph reads it: the step's ``result``, the
    returns its pose took (``scan_points`` ``(N, 2)``, scanner frame, m), the odometry noise factors learned
    up to it and the range noise model in force."""

    result: StepResult
    scan_points: FloatArray
    noise_scale: NoiseScale
    range_noise: RangeNoise

    @classmethod
    def of(cls, front: Pipeline, result: StepResult) -> Tracked:
        """What ``front`` made of the scan it has just stepped (``result``). O(1)."""
        return cls(result, front.scan_points, front.odometry_noise.scale, front.range_noise)


class FrontEndProcessError(SlamError):
    """The front end's child process failed in a way that could not be carried back as it was."""


def _child(
    config: PipelineConfig, laser_offset: Pose2D, inbox: Any, outbox: Any, parent: int
) -> None:  # pragma: no cover - runs in the child process (tests cover it through FrontEndProcess)
    """The child: step a tracking-only pipeline through the scans of ``inbox`` (batches of ``(scan,
    odometry)``, ``None`` at the end), putting a batch of :class:`Tracked` on ``outbox`` for each, then
    ``("done", (median_ms, p99_ms))``; an error goes as ``("error", exception or text)``."""
    _orphan_watch(parent)
    try:
        front = Pipeline(config, laser_offset=laser_offset, track_only=True)
        while (batch := inbox.get()) is not None:
            out = []
            for scan, odometry in batch:
                out.append(Tracked.of(front, front.step(scan, odometry)))
            outbox.put(("tracked", out))
        front.flush()
        outbox.put(("done", front.timing_ms()))
    except BaseException as exc:  # everything goes back to the parent, which decides
        try:
            pickle.loads(pickle.dumps(exc))
            outbox.put(("error", exc))
        except Exception:
            outbox.put(("error", f"{type(exc).__name__}: {exc}"))


def _orphan_watch(parent: int) -> None:  # pragma: no cover - runs in the child process
    """End the child at once when its parent process is gone (killed: nobody is left to say so, and a
    read of a message the parent was half-way through writing would wait for ever). Checked every half
    second on a daemon thread, whatever the child's main thread is blocked on."""

    def watch() -> None:
        while True:
            if os.getppid() != parent:
                os._exit(0)
            time.sleep(0.5)

    threading.Thread(target=watch, name="linemap-front-end-watch", daemon=True).start()


class FrontEndProcess:
    """A tracking-only front end (``Pipeline(config, laser_offset, track_only=True)``) in a child process
    (module docstring). Use as a context manager; not thread-safe beyond one sender and one reader."""

    def __init__(self, config: PipelineConfig, laser_offset: Pose2D, *, ahead: int = 256) -> None:
        # fork on Linux: the child starts at once with what is imported here (spawn would import numpy,
        # numba and the kernels again, about a second); elsewhere fork is unsafe or missing
        fork = sys.platform.startswith("linux") and "fork" in mp.get_all_start_methods()
        ctx = mp.get_context("fork") if fork else mp.get_context("spawn")
        self._inbox: Any = ctx.Queue(maxsize=max(ahead // BATCH, 1))
        self._outbox: Any = ctx.Queue()
        self._process = ctx.Process(
            target=_child,
            args=(config, laser_offset, self._inbox, self._outbox, os.getpid()),
            name="linemap-front-end",
            daemon=True,
        )
        self._batch: list[tuple[Scan, Pose2D | None]] = []
        self._closed = False
        self.timing_ms: tuple[float, float] = (0.0, 0.0)

    def __enter__(self) -> FrontEndProcess:
        self._process.start()
        # this side only reads the results: without its own copy of their pipe's write end, a child killed
        # half-way through writing one leaves an end of file here (EOFError), not a read that waits forever
        self._outbox._writer.close()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()

    def send(self, scan: Scan, odometry: Pose2D | None = None) -> None:
        """Queue one scan for the front end (blocks while the child is ``ahead`` scans ahead)."""
        self._batch.append((scan, odometry))
        if len(self._batch) >= BATCH:
            self._flush()

    def close_input(self) -> None:
        """No more scans: the child finishes those sent and reports its step times."""
        if not self._closed:
            self._flush()
            self._put(None)
            self._closed = True

    @property
    def input_closed(self) -> bool:
        """Whether :meth:`close_input` was called."""
        return self._closed

    def _flush(self) -> None:
        if self._batch:
            self._put(self._batch)
            self._batch = []

    def _put(self, item: Any) -> None:
        """Put ``item`` on the child's bounded queue, waiting while it is full; a child that died meanwhile
        is named (:class:`FrontEndProcessError`), not waited for forever."""
        while True:
            try:
                self._inbox.put(item, timeout=1.0)
                return
            except queue.Full:
                if not self._process.is_alive():
                    raise FrontEndProcessError(
                        f"the front end's process ended with exit code {self._process.exitcode} "
                        "before it took the scans sent"
                    ) from None

    def results(self) -> Iterator[Tracked]:
        """One :class:`Tracked` per scan sent, in order, until the child has finished those sent before
        :meth:`close_input`; raises the child's error."""
        while True:
            kind, payload = self._next()
            if not kind:
                if not self._process.is_alive():
                    raise FrontEndProcessError(
                        f"the front end's process ended with exit code {self._process.exitcode} "
                        "before it finished the scans sent"
                    ) from None
                continue
            if kind == "tracked":
                yield from payload
            elif kind == "done":
                self.timing_ms = payload
                return
            elif isinstance(payload, LinemapError):
                raise payload
            elif isinstance(payload, BaseException):
                raise FrontEndProcessError(
                    f"the front end failed: {type(payload).__name__}: {payload}"
                ) from payload
            else:
                raise FrontEndProcessError(f"the front end failed: {payload}")

    def _next(self) -> tuple[str, Any]:
        """The child's next message, or ``("", None)`` after a second without one or once the child's end
        of the pipe is closed."""
        try:
            message: tuple[str, Any] = self._outbox.get_nowait()
            return message
        except queue.Empty:
            self._flush()  # the scans waiting for their batch to fill may be the ones waited for
        except (EOFError, OSError):  # the child is gone (or died mid-message): the caller names it
            return "", None
        try:
            message = self._outbox.get(timeout=1.0)
            return message
        except (queue.Empty, EOFError, OSError):  # nothing yet, or the child died mid-message
            return "", None

    def stop(self) -> None:
        """Stop the child (at once if it is still working) and release the queues."""
        if self._process.is_alive():
            self._process.terminate()
        if self._process.pid is not None:
            self._process.join(timeout=5.0)
        for q in (self._inbox, self._outbox):
            q.cancel_join_thread()
            q.close()
