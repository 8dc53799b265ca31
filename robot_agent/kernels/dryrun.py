"""Checks and loading of a downloaded kernel in worker processes (docs/reliability/sandbox.md).

:func:`verify_in_worker` runs the dry run (the kernel applied to the inputs its stage would see on the
last scans) and the conformance battery in a fresh, confined worker (:mod:`robot_agent.kernels.worker`) with a
wall-time budget per phase, a CPU-time limit (RLIMIT_CPU) and a memory limit (RLIMIT_AS), then kills it.
:func:`load_in_worker` starts the long-lived worker a kernel that passed serves from, and returns the
kernel class that forwards to it (:func:`robot_agent.kernels.proc.remote_class`). Both are called on the
poller thread and return within their limits whatever the kernel does: a kernel that hangs or spins at
import, in the dry run or in the battery is killed at its limit and refused with the reason.
"""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from robot_agent.errors import AgentError, KernelRejected
from robot_agent.kernels.proc import KernelWorker, WorkerError, remote_class
from shared.kernels import Kernel, Stage
from shared.types import Scan

__all__ = [
    "STARTUP_ALLOWANCE_S",
    "DryRunReport",
    "dry_run",
    "load_in_worker",
    "verify_in_worker",
]

#: Seconds a worker may take to start: spawn a Python interpreter, import numpy and the kernels, warm the
#: built-ins up (~1 s on a desktop, a few seconds on a small robot computer) and build the stage inputs with
#: the built-in kernels. Not counted in the kernel's budget, which starts once the worker is confined.
STARTUP_ALLOWANCE_S = 30.0


@dataclass(frozen=True, slots=True)
class DryRunReport:
    """Timing of a successful dry run (milliseconds of wall-clock time).

    ``calls``: ``apply`` calls made (one per stage input); ``median_ms`` / ``max_ms``: per call, in the
    worker; ``load_ms``: constructing the kernel; ``startup_ms``: starting and confining the worker and
    building the inputs (not the kernel's cost); ``total_ms``: the agent's wait for the import and the run.
    """

    calls: int
    median_ms: float
    max_ms: float
    load_ms: float
    startup_ms: float
    total_ms: float


def _start(
    label: str,
    stage: Stage,
    memory_mb: float,
    cpu_s: int | None,
    startup_s: float,
    scans: Sequence[Scan] | None,
) -> tuple[KernelWorker, int]:
    """A confined worker (after building the dry run's inputs from ``scans``, if given): it, and the
    number of inputs. :class:`AgentError` when it cannot start (not the kernel's fault)."""
    try:
        worker = KernelWorker(
            label, stage, memory_mb, cpu_s, startup_s, role="checks" if scans is not None else "service"
        )
    except AgentError:
        raise
    try:
        n = 0
        if scans is not None:
            got = worker.request(
                {"op": "inputs", "stage": str(stage), "scans": list(scans)}, startup_s, "building the inputs"
            )
            if "error" in got:
                raise AgentError(f"dry run of {label}: could not build the inputs: {got['error']}")
            n = worker.parse(got, int, "building the inputs")
        worker.confine()
        return worker, n
    except WorkerError as exc:
        worker.close()
        raise AgentError(f"kernel worker for {label} did not start: {exc.reason}") from None
    except BaseException:
        worker.close()
        raise


def _load(
    worker: KernelWorker, source: bytes, stage: Stage, name: str, version: str, timeout_s: float
) -> dict[str, Any]:
    got = worker.request(
        {"op": "load", "source": source.hex(), "stage": str(stage), "name": name, "version": version},
        timeout_s,
        "the import",
    )
    if "error" in got:
        raise KernelRejected(str(got["error"]))
    meta: dict[str, Any] = worker.parse(got, dict, "the import")
    return meta


def _problems(ident: str, problems: list[str]) -> str:
    shown = "; ".join(problems[:10])
    more = f"; and {len(problems) - 10} more" if len(problems) > 10 else ""
    n = len(problems)
    return f"conformance failed for {ident} ({n} problem{'s' if n > 1 else ''}): {shown}{more}"


def verify_in_worker(
    source: bytes,
    stage: Stage | str,
    name: str,
    version: str,
    params: Mapping[str, Any] | None,
    scans: Sequence[Scan],
    budget_s: float,
    memory_limit_mb: float = 512,
    startup_s: float = STARTUP_ALLOWANCE_S,
    conformance_s: float | None = None,
    started: list[float] | None = None,
) -> DryRunReport:
    """The dry run, then (with ``conformance_s``) the conformance battery, in one confined worker.

    The dry run: import + construction + one ``apply`` per stage input
    (:func:`shared.pipeline.probe.stage_inputs`) within ``budget_s`` in all, each result checked; the
    battery within ``conformance_s``. The worker's address space is its start-up footprint plus
    ``memory_limit_mb``; its CPU time after start-up is limited to
    the two budgets plus 2 s (RLIMIT_CPU: SIGXCPU, then SIGKILL). Raises :class:`KernelRejected`
    ("dry run: ..." or "conformance ...") naming what the kernel did; :class:`AgentError` when the worker
    cannot start or build its inputs. The worker is always killed before this returns. ``started``, if
    given, gets the ``time.perf_counter()`` at which the kernel's code began (after the worker's start-up).
    """
    want = Stage(stage)
    label = f"{name} {version}"
    cpu_s = math.ceil(budget_s + (conformance_s or 0.0)) + 2
    t_start = time.perf_counter()
    worker, n_inputs = _start(label, want, memory_limit_mb, cpu_s, startup_s, scans)
    startup_ms = (time.perf_counter() - t_start) * 1e3
    t_run = time.perf_counter()
    if started is not None:
        started.append(t_run)
    phase = "dry run"
    try:
        try:
            _load(worker, source, want, name, version, budget_s)
            left = max(0.001, budget_s - (time.perf_counter() - t_run))
            got = worker.request({"op": "dry-run", "params": dict(params or {})}, left, "the dry run")
            total_ms = (time.perf_counter() - t_run) * 1e3
            if "error" in got:
                raise KernelRejected(str(got["error"]))
            times, load_ms = worker.parse(
                got, lambda ok: ([float(t) for t in ok["times"]], float(ok["load_ms"])), "the dry run"
            )
            if conformance_s is not None:
                phase = "conformance"
                checked = worker.request(
                    {"op": "conformance", "params": dict(params or {})}, conformance_s, "the battery"
                )
                if "error" in checked:
                    raise KernelRejected(f"conformance battery: {checked['error']}")
                problems = worker.parse(checked, lambda ok: [str(p) for p in ok], "the battery")
                if problems:
                    raise KernelRejected(_problems(f"{want}/{name}@{version}", problems))
        except WorkerError as exc:
            raise KernelRejected(
                _failure_reason(phase, exc, budget_s, conformance_s, n_inputs, memory_limit_mb)
            ) from None
        except KernelRejected as exc:
            if phase == "dry run":
                raise KernelRejected(f"dry run: {exc.reason}") from None
            raise
    finally:
        worker.close()
    return DryRunReport(
        calls=len(times),
        median_ms=statistics.median(times) if times else 0.0,
        max_ms=max(times, default=0.0),
        load_ms=load_ms,
        startup_ms=startup_ms,
        total_ms=total_ms,
    )


def _failure_reason(
    phase: str,
    exc: WorkerError,
    budget_s: float,
    conformance_s: float | None,
    n_inputs: int,
    memory_mb: float,
) -> str:
    hung = "did not return within" in exc.reason
    if phase == "dry run":
        if hung:
            inputs = f"{n_inputs} input{'s' if n_inputs != 1 else ''}"
            budget = f"{budget_s * 1e3:.0f} ms budget"
            return f"dry run: ran longer than its {budget} ({inputs}); the process was killed"
        return (
            f"dry run: the kernel's process died without reporting ({exc.reason}; out of memory with the"
            f" {memory_mb:g} MB limit, past its CPU limit, or a crash in native code)"
        )
    if hung:
        return (
            f"conformance battery: did not finish within {conformance_s:g} s (a check hangs, e.g. on"
            " empty input); the process was killed"
        )
    return f"conformance battery: the kernel's process died ({exc.reason})"


def dry_run(
    source: bytes,
    stage: Stage | str,
    name: str,
    version: str,
    params: Mapping[str, Any] | None,
    scans: Sequence[Scan],
    budget_s: float,
    memory_limit_mb: int = 512,
    startup_s: float = STARTUP_ALLOWANCE_S,
) -> DryRunReport:
    """The dry run alone (:func:`verify_in_worker` without the battery); same limits and errors."""
    return verify_in_worker(source, stage, name, version, params, scans, budget_s, memory_limit_mb, startup_s)


def load_in_worker(
    source: bytes,
    stage: Stage | str,
    name: str,
    version: str,
    *,
    memory_mb: float,
    call_s: float,
    import_s: float,
    startup_s: float = STARTUP_ALLOWANCE_S,
) -> type[Kernel[Any]]:
    """Start the long-lived confined worker a downloaded kernel runs in and import it there.

    Returns the class to register (:func:`robot_agent.kernels.proc.remote_class`): constructing it and each
    ``apply`` run in the worker within ``call_s``. The worker has ``memory_mb`` of address space above its
    footprint and no CPU limit (a per-call wall-time limit instead). Raises :class:`KernelRejected` when
    the import fails or takes longer than ``import_s`` (the worker is killed), :class:`AgentError` when
    the worker cannot start. The worker dies with the agent.
    """
    want = Stage(stage)
    label = f"{name} {version}"
    worker, _ = _start(label, want, memory_mb, None, startup_s, None)
    try:
        meta = _load(worker, source, want, name, version, import_s)
    except WorkerError as exc:
        raise KernelRejected(f"import in its worker failed: {exc.reason}") from None
    except BaseException:
        worker.close()
        raise
    return remote_class(worker, want, name, version, meta, call_s)
