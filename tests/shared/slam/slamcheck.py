"""Helpers of the loop-closure tests: a worker held back until the step says so, and the check that two
mappers ended on the same map."""

from __future__ import annotations

import threading

import numpy as np

from shared.pipeline import MapperState
from shared.pipeline.pipeline import StepResult
from shared.slam import OnlineGraphMapper
from shared.slam.online import SEARCH_LAG_STEPS, _Redraw, _Search
from shared.types import Pose2D, Scan


class LateWorker:
    """Holds an :class:`OnlineGraphMapper`'s worker back: a loop search runs only once the step before
    the one its closures are due at is over (as late as it can be without the step waiting long), a
    rebuild only ``SEARCH_LAG_STEPS - 1`` steps after the one it began at (the latest that holds back no
    search queued behind it), or at :meth:`release`. The test steps through :meth:`step`, which tells the
    worker how far the robot is. No sleeping: the order is forced."""

    def __init__(self, online: OnlineGraphMapper) -> None:
        self.online = online
        self._now = online.version
        self._released = False
        self._cond = threading.Condition()
        run = online._run

        def late(job: _Search | _Redraw) -> None:
            at = job.due - 1 if isinstance(job, _Search) else job.at + SEARCH_LAG_STEPS - 1
            with self._cond:
                self._cond.wait_for(lambda: self._released or self._now >= at)
            run(job)

        online._run = late  # type: ignore[method-assign]

    def step(self, scan: Scan, odometry: Pose2D | None = None) -> StepResult:
        result = self.online.step(scan, odometry)
        with self._cond:
            self._now = result.version
            self._cond.notify_all()
        return result

    def release(self) -> None:
        """Let every job run (before ``flush``, which waits for them all)."""
        with self._cond:
            self._released = True
            self._cond.notify_all()


def state_when(online: OnlineGraphMapper, late: LateWorker, scans: list, moment) -> tuple[MapperState, int]:  # type: ignore[no-untyped-def, type-arg]
    """Step ``late`` (holding ``online``'s worker back) through ``scans`` until ``moment(step)`` holds, take
    the state then, let the worker go and close ``online``: the state and the steps taken. Fails if the
    moment never came."""
    split = 0
    try:
        for split, scan in enumerate(scans, 1):
            late.step(scan)
            if moment(split):
                break
        state = online.state()
        late.release()
    finally:
        online.close()
    assert split < len(scans), "the moment never came"
    return state, split


def assert_same_map(a: OnlineGraphMapper, b: OnlineGraphMapper) -> None:
    """The same keyframes, closures, walls (ids and end points) and trajectory, bit for bit."""
    assert a.closures == b.closures > 0
    assert a.closure_pairs() == b.closure_pairs()
    np.testing.assert_array_equal(a.keyframe_rows(), b.keyframe_rows())
    ids_a, walls_a = a.walls()
    ids_b, walls_b = b.walls()
    np.testing.assert_array_equal(ids_a, ids_b)
    np.testing.assert_array_equal(walls_a, walls_b)
    np.testing.assert_array_equal(a.trajectory(), b.trajectory())
