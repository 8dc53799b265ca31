"""The front end in a child process ahead of the pose graph (shared/slam/frontproc.py, used by
``map_scans`` with loop closure): the same map as in one process, bit for bit; a broken record, a front
end that raises and a child that dies all end the run with a clear error."""

from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from shared.errors import LinemapError
from shared.mapping import MappingStoppedError, Source, map_scans, open_source
from shared.pipeline import Pipeline, PipelineConfig
from shared.pipeline.pipeline import StepResult
from shared.sim import default_world, simulate_run
from shared.slam import LoopClosureSettings
from shared.slam.frontproc import FrontEndProcess, FrontEndProcessError
from shared.types import Pose2D, Scan

LOOPS = LoopClosureSettings()


def _run(front_process: bool, limit: int | None = None):  # type: ignore[no-untyped-def]
    return map_scans(
        open_source("sim"), PipelineConfig(), loop_closure=LOOPS, limit=limit, front_process=front_process
    )


def test_the_map_is_the_one_process_map_bit_for_bit() -> None:
    """The default world's patrol closes loops; with the front end in a child process the walls, their
    ids, the corrected trajectory, the closures and the ICP count are those of one process."""
    alone, beside = _run(False), _run(True)
    assert alone.loop_closures >= 3  # the case exercises the graph
    assert beside.loop_closures == alone.loop_closures
    assert (beside.scans, beside.icp_used) == (alone.scans, alone.icp_used)
    assert pickle.dumps(beside.snapshot) == pickle.dumps(alone.snapshot)
    assert beside.step_median_ms > 0.0  # the child's step times come back


def test_the_limit_is_read_and_no_more() -> None:
    run = _run(True, limit=37)
    assert run.scans == 37
    assert len(run.snapshot.trajectory) == 37


def _scans_then_broken(n: int) -> Iterator[Scan]:
    run = simulate_run(default_world(), seed=0)
    yield from run.scans[:n]
    raise LinemapError("line 1234: expected 181 ranges, found 7")


def test_a_broken_record_keeps_what_was_mapped_before_it() -> None:
    source = Source("broken log", _scans_then_broken(60), Pose2D(), None)
    with pytest.raises(MappingStoppedError) as caught:
        map_scans(source, PipelineConfig(), loop_closure=LOOPS, front_process=True)
    assert caught.value.run.scans == 60
    assert "expected 181 ranges" in str(caught.value)


class KernelFailedError(LinemapError):
    pass


def patch_step(monkeypatch: pytest.MonkeyPatch, at: int, act: Callable[[], None]) -> None:
    """Make the ``at``-th call of ``Pipeline.step`` in the front end's process ``act`` first. The child is
    forked from this process, so a step patched here is patched there."""
    if not sys.platform.startswith("linux"):
        pytest.skip("the patch reaches the child only by fork")
    calls = {"n": 0}
    step = Pipeline.step

    def patched(self: Pipeline, scan: Scan, odometry: Pose2D | None = None, **kw: object) -> StepResult:
        calls["n"] += 1
        if calls["n"] == at:
            act()
        return step(self, scan, odometry, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(Pipeline, "step", patched)


def test_a_front_end_error_in_the_child_is_raised_as_it_was(monkeypatch: pytest.MonkeyPatch) -> None:
    def fail() -> None:
        raise KernelFailedError("kernel 'icp' raised: matrix is singular")

    patch_step(monkeypatch, 25, fail)
    with pytest.raises(KernelFailedError, match="matrix is singular"):
        _run(True, limit=60)


def test_a_child_that_dies_is_named(monkeypatch: pytest.MonkeyPatch) -> None:
    patch_step(monkeypatch, 10, lambda: os.kill(os.getpid(), signal.SIGKILL))
    with pytest.raises(FrontEndProcessError, match="exit code -9"):
        _run(True, limit=60)


def test_leaving_early_stops_the_child() -> None:
    run = simulate_run(default_world(), seed=0)
    with FrontEndProcess(PipelineConfig(), Pose2D()) as child:
        for scan in run.scans[:20]:
            child.send(scan)
        first = next(iter(child.results()))
        assert first.result.version == 1
        process = child._process
    assert not process.is_alive()


_STUCK_PARENT = """
import threading
from shared.mapping import Source, map_scans
from shared.pipeline import PipelineConfig
from shared.sim import default_world, simulate_run
from shared.slam import LoopClosureSettings
from shared.types import Pose2D

run = simulate_run(default_world(), seed=0)

def scans():
    yield from run.scans[:30]
    threading.Event().wait()  # the input stalls: the parent waits here, the child for scans

map_scans(Source("stalled", scans(), Pose2D(), None), PipelineConfig(), loop_closure=LoopClosureSettings(),
          front_process=True)
"""


def _children(pid: int) -> list[int]:
    path = Path(f"/proc/{pid}/task/{pid}/children")
    return [int(c) for c in path.read_text().split()] if path.exists() else []


def _running(pid: int) -> bool:
    """Whether ``pid`` exists and is not a zombie waiting to be reaped."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def test_the_child_does_not_outlive_a_killed_parent() -> None:
    """``kill -9`` of ``linemap map``: nobody is left to tell the child, which must end by itself."""
    if not Path("/proc/self/task").exists():
        pytest.skip("reads the process tree from /proc")
    parent = subprocess.Popen([sys.executable, "-c", _STUCK_PARENT])
    try:
        deadline = time.monotonic() + 120.0
        while not (kids := _children(parent.pid)):
            assert parent.poll() is None, "the mapping process ended before it started its child"
            assert time.monotonic() < deadline, "no front-end child process appeared"
            time.sleep(0.05)
    finally:
        parent.kill()
        parent.wait()
    deadline = time.monotonic() + 60.0
    while any(_running(k) for k in kids):
        assert time.monotonic() < deadline, f"the front end's process {kids} outlived its parent"
        time.sleep(0.05)


def test_a_child_killed_while_the_sender_waits_is_named() -> None:
    """The child gone while its bounded queue is full: sending names it instead of waiting forever (the
    join below only bounds a hang, should one come back)."""
    run = simulate_run(default_world(), seed=0)
    raised: list[BaseException] = []
    with FrontEndProcess(PipelineConfig(), Pose2D(), ahead=8) as child:
        pid = child._process.pid
        assert pid is not None
        os.kill(pid, signal.SIGKILL)
        child._process.join(30)

        def send_all() -> None:
            try:
                for scan in run.scans[:200]:
                    child.send(scan)
                child.close_input()
                list(child.results())
            except FrontEndProcessError as exc:
                raised.append(exc)

        sender = threading.Thread(target=send_all, daemon=True)
        sender.start()
        sender.join(120)
    assert not sender.is_alive(), "the sender still waits for a dead child"
    assert raised and "exit code -9" in str(raised[0])
