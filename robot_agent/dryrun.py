"""Checks and loading of a downloaded kernel in worker processes (docs/reliability/sandbox.md).

:func:`verify_in_worker` runs the dry run (the kernel applied to the inputs its stage would see on the
last scans) and the conformance battery in a fresh, confined worker (:mod:`robot_agent.worker`) with a
wall-time budget per phase, a CPU-time limit (RLIMIT_CPU) and a memory limit (RLIMIT_AS), then kills it.
:func:`load_in_worker` starts the long-lived worker a kernel that passed serves from, and returns the
kernel class that forwards to it (:func:`robot_agent.kernelproc.remote_class`). Both are called on the
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

import numpy as np

from robot_agent.errors import AgentError, KernelRejected
from robot_agent.kernelproc import KernelWorker, WorkerError, remote_class
from shared.kernels import REGISTRY, Kernel, Stage
from shared.kernels.conformance import moved_copy
from shared.types import FloatArray, IntArray, Pose2D, Scan

__all__ = [
    "DEFAULT_INPUT_KERNELS",
    "STARTUP_ALLOWANCE_S",
    "DryRunReport",
    "dry_run",
    "load_in_worker",
    "stage_inputs",
    "verify_in_worker",
]

#: The default pipeline's kernels (``PipelineConfig()``) used to derive what each stage sees in a dry run.
DEFAULT_INPUT_KERNELS: Mapping[Stage, str] = {
    Stage.SEGMENTATION: "abd-iepf",
    Stage.NOISE_REMOVAL: "dbscan",
    Stage.CLUSTERING: "kmeans",
}

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

    The dry run: import + construction + one ``apply`` per stage input (:func:`stage_inputs`) within
    ``budget_s`` in all, each result checked; the battery within ``conformance_s``. The worker's address
    space is its start-up footprint plus ``memory_limit_mb``; its CPU time after start-up is limited to
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

    Returns the class to register (:func:`robot_agent.kernelproc.remote_class`): constructing it and each
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


def stage_inputs(stage: Stage, scans: Sequence[Scan]) -> list[tuple[tuple[Any, ...], int]]:
    """``(apply args, n_in)`` per scan for ``stage`` (straight-line: points form, then centroids form)."""
    if not scans:
        from shared.kernels.conformance import room_scan

        scans = [room_scan()]
    seg_k: Any = REGISTRY.create(Stage.SEGMENTATION, DEFAULT_INPUT_KERNELS[Stage.SEGMENTATION])
    noise_k: Any = REGISTRY.create(Stage.NOISE_REMOVAL, DEFAULT_INPUT_KERNELS[Stage.NOISE_REMOVAL])
    cluster_k: Any = REGISTRY.create(Stage.CLUSTERING, DEFAULT_INPUT_KERNELS[Stage.CLUSTERING])
    out: list[tuple[tuple[Any, ...], int]] = []
    previous: tuple[Scan, FloatArray] | None = None
    for scan in scans:
        if stage == Stage.SEGMENTATION:
            out.append(((scan,), len(scan.ranges_m)))
            continue
        seg = seg_k.apply(scan)
        pts = np.asarray(seg.points)
        if stage == Stage.NOISE_REMOVAL:
            out.append(((pts,), len(pts)))
        elif stage == Stage.SCAN_MATCHING:
            if previous is None:
                if len(scans) == 1:
                    out.append(((pts, moved_copy(pts), Pose2D()), len(pts)))
            else:
                prev_scan, prev_pts = previous
                initial = Pose2D()
                if prev_scan.odometry is not None and scan.odometry is not None:
                    initial = prev_scan.odometry.between(scan.odometry)
                out.append(((prev_pts, pts, initial), len(pts)))
            previous = (scan, pts)
        else:
            clean = noise_k.apply(pts)
            groups = np.asarray(seg.labels)[np.asarray(clean.keep)]
            denoised = np.asarray(clean.points)
            if len(denoised) > len(groups):  # a noise kernel that adds points: they join no segment
                groups = np.concatenate([groups, np.full(len(denoised) - len(groups), -1, dtype=np.intp)])
            if stage == Stage.CLUSTERING:
                out.append(((denoised,), len(denoised)))
            else:
                out.append(((denoised, groups), len(denoised)))
                cents, cgroups = _centroids(cluster_k, denoised, groups)
                out.append(((cents, cgroups), len(cents)))
    return out


def _centroids(kernel: Any, points: FloatArray, groups: IntArray) -> tuple[FloatArray, IntArray]:
    """k-means centroids per segment (about one per 15 points, at least 2), in order along the segment."""
    cents: list[FloatArray] = []
    cgroups: list[IntArray] = []
    for g in np.unique(groups[groups >= 0]):
        block = points[groups == g]
        if len(block) < 2:
            continue
        k = min(len(block), max(2, len(block) // 15))
        c = np.asarray(kernel.with_params(n_clusters=k).apply(block).centroids)
        centred = c - c.mean(axis=0)
        axis = np.linalg.svd(centred, full_matrices=False)[2][0] if len(c) > 1 else np.zeros(2)
        cents.append(c[np.argsort(centred @ axis, kind="stable")])
        cgroups.append(np.full(len(c), g, dtype=np.intp))
    if not cents:
        return np.zeros((0, 2)), np.zeros(0, dtype=np.intp)
    return np.vstack(cents), np.concatenate(cgroups)
