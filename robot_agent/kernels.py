"""Checks a downloaded kernel passes before the agent may run it (issue 5 item 4, SPEC §7, §9).

The agent installs a kernel only after every step below succeeded, cheapest first; each refusal raises
:class:`~robot_agent.errors.KernelRejected` whose ``reason`` is what the server (and the operator) is told:

1. :func:`verify_artifact`: the SHA-256 of the source matches the message's, and an Ed25519 signature by a
   key the robot trusts covers it (unsigned code only with the ``--allow-unsigned`` development flag);
2. :func:`dry_run`: in a separate, memory-limited process, the module is imported and the kernel applied to
   the inputs its stage would see on the last stored scans, within a wall-clock budget;
3. :func:`load_kernel_class`: the module is imported in the agent, in its own module namespace, and the one
   kernel class it declares for the requested stage/name/version is returned (never registered here);
4. :func:`check_conformance`: the conformance battery of :mod:`shared.kernels.conformance`.

Then the agent registers the class (``REGISTRY.register``) and swaps it in between two steps. Doing the dry
run before importing the module in the agent means code that hangs or eats memory at import time or on
real data is caught in the child process, where it can be killed. (The conformance battery still runs the
kernel in the agent's process on small synthetic inputs; the signature is what makes that acceptable.)

Nothing here touches the database or the network.
"""

from __future__ import annotations

import contextlib
import inspect
import multiprocessing
import statistics
import sys
import threading
import time
import types
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import Any

import numpy as np
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

from robot_agent.errors import AgentError, KernelRejected
from shared.errors import LinemapError
from shared.kernels import (
    REGISTRY,
    ClusteringKernel,
    Kernel,
    KernelRegistry,
    NoiseRemovalKernel,
    ScanMatchingKernel,
    SegmentationKernel,
    Stage,
    StraightLineKernel,
)
from shared.kernels.conformance import check_kernel, check_result, moved_copy
from shared.signing import SignatureError, key_id, sha256_hex, verify_digest
from shared.types import FloatArray, IntArray, Pose2D, Scan

__all__ = [
    "DEFAULT_INPUT_KERNELS",
    "STARTUP_ALLOWANCE_S",
    "DryRunReport",
    "check_conformance",
    "dry_run",
    "load_kernel_class",
    "module_name",
    "verify_artifact",
]

#: The default pipeline's kernels (``PipelineConfig()``) used to derive what each stage sees in a dry run.
DEFAULT_INPUT_KERNELS: Mapping[Stage, str] = {
    Stage.SEGMENTATION: "abd-iepf",
    Stage.NOISE_REMOVAL: "dbscan",
    Stage.CLUSTERING: "kmeans",
}

#: Seconds the dry-run child may take to start: spawn a Python interpreter, import numpy and the kernels
#: (~0.5 s on a desktop, a few seconds on a small robot computer) and build the stage inputs from the scans
#: with the built-in kernels. Not counted in the kernel's budget: the budget clock starts once the child
#: reports it is ready, and covers importing the kernel's module plus every ``apply`` call.
STARTUP_ALLOWANCE_S = 30.0

_STAGE_BASES: Mapping[Stage, type[Kernel[Any]]] = {
    Stage.SEGMENTATION: SegmentationKernel,
    Stage.NOISE_REMOVAL: NoiseRemovalKernel,
    Stage.CLUSTERING: ClusteringKernel,
    Stage.STRAIGHT_LINE: StraightLineKernel,
    Stage.SCAN_MATCHING: ScanMatchingKernel,
}

#: Serialises module loads: the registry diff that undoes a module's self-registration needs it.
_LOAD_LOCK = threading.Lock()

_UNSIGNED = "unsigned kernel refused; run the agent with --allow-unsigned for development"


# --------------------------------------------------------------------------------------- 1. the artifact
def verify_artifact(
    source: bytes,
    sha256: str,
    signature: str | None,
    trusted: Sequence[Ed25519PublicKey],
    allow_unsigned: bool = False,
) -> str | None:
    """Check a kernel artifact's digest and signature; return the id of the key that signed it.

    ``sha256`` is the hex digest the control message names, ``signature`` the base64 Ed25519 signature over
    it (:func:`shared.signing.sign_digest`), ``trusted`` the public keys this robot accepts. Returns the
    signing key's id, or ``None`` for unsigned code accepted because ``allow_unsigned`` is set (development
    only). A signature that is present is always checked, even with ``allow_unsigned``.

    Raises :class:`KernelRejected`: "sha256 mismatch: expected X, got Y"; "unsigned kernel refused; ...";
    no trusted keys configured; a signature that is malformed or verifies with none of the keys.
    O(len(source)) for the hash, then ~0.1 ms per trusted key.
    """
    got = sha256_hex(source)
    if got != sha256.strip().lower():
        raise KernelRejected(f"sha256 mismatch: expected {sha256}, got {got}")
    if not signature:
        if allow_unsigned:
            return None
        raise KernelRejected(_UNSIGNED)
    if not trusted:
        raise KernelRejected(
            "signed kernel refused: this robot trusts no signing key; add the operator's public key"
            " (linemap keys generate prints it) to the agent's trusted keys"
        )
    failures: list[str] = []
    for key in trusted:
        try:
            verify_digest(key, got, signature)
        except SignatureError as exc:
            failures.append(str(exc))
            continue
        return key_id(key)
    if any(not f.startswith("signature does not verify") for f in failures):
        malformed = next(f for f in failures if not f.startswith("signature does not verify"))
        raise KernelRejected(f"bad signature: {malformed}")
    ids = ", ".join(key_id(k) for k in trusted)
    raise KernelRejected(f"bad signature: it verifies with none of the trusted keys ({ids})")


# ------------------------------------------------------------------------------------------ 2. loading
def module_name(name: str, version: str) -> str:
    """The module name a kernel's source is imported under: ``linemap_kernel_<name>_<version>``.

    Characters other than letters, digits and ``_`` become ``_`` (``my-dbscan``, ``1.2.0`` ->
    ``linemap_kernel_my_dbscan_1_2_0``).
    """
    raw = f"linemap_kernel_{name}_{version}"
    return "".join(c if c.isalnum() or c == "_" else "_" for c in raw)


def _source_file(stage: Stage | str, name: str, version: str) -> str:
    return f"<kernel {stage}/{name}@{version}>"


def _stage(stage: Stage | str) -> Stage:
    try:
        return Stage(stage)
    except ValueError:
        known = ", ".join(s.value for s in Stage)
        raise KernelRejected(f"unknown stage {stage!r}: expected one of {known}") from None


def _line_in(exc: BaseException, filename: str) -> int | None:
    """The line of the kernel source (``filename``) where ``exc`` was raised, innermost first."""
    if isinstance(exc, SyntaxError) and exc.filename == filename:
        return exc.lineno
    line = None
    tb = exc.__traceback__
    while tb is not None:
        if tb.tb_frame.f_code.co_filename == filename:
            line = tb.tb_lineno
        tb = tb.tb_next
    return line


def _describe(exc: BaseException, filename: str) -> str:
    """``"ExcType: message (line N)"`` with N the innermost line of the kernel's own source, if any."""
    message = exc.msg if isinstance(exc, SyntaxError) else str(exc)
    line = _line_in(exc, filename)
    where = f" (line {line})" if line is not None else ""
    return f"{type(exc).__name__}: {message}{where}"


def _ident(cls: type[Any]) -> str:
    return f"{getattr(cls, 'stage', '?')}/{getattr(cls, 'name', cls.__name__)}@{getattr(cls, 'version', '?')}"


def _undo_registrations(before: dict[tuple[Stage, str, str], type[Kernel[Any]]], modname: str) -> None:
    """Undo what executing module ``modname`` did to the global registry.

    Removes every class the module registered (its ``__module__`` is ``modname``) and puts back any
    built-in (a class from ``shared``) it removed. Entries of other downloaded kernels are left alone, so a
    registration or deletion the agent makes meanwhile from another thread is never reverted.
    """
    for info in list(REGISTRY):
        key = (info.stage, info.name, info.version)
        if info.cls.__module__ == modname and before.get(key) is not info.cls:
            REGISTRY.unregister(*key)
    now = {(i.stage, i.name, i.version): i.cls for i in REGISTRY}
    for key, cls in before.items():
        if cls.__module__.startswith("shared.") and now.get(key) is not cls:
            with contextlib.suppress(LinemapError):
                REGISTRY.register(cls)


def load_kernel_class(source: bytes, stage: Stage | str, name: str, version: str) -> type[Kernel[Any]]:
    """Import a kernel's source in a fresh module and return its kernel class for ``stage/name@version``.

    The module is compiled and executed in its own namespace named :func:`module_name`; it stays in
    ``sys.modules`` on success (pydantic parameter models and dataclasses resolve annotations through it;
    a previous module of the same name is replaced) and is removed on any failure (the previous one is
    put back). The module must define exactly one concrete :class:`Kernel` subclass of the stage's base
    with the requested stage, name and version; its declaration is checked as ``REGISTRY.register`` would.
    Nothing is left in the global :data:`REGISTRY`: registrations the module made (``@register``) are
    undone, built-ins it removed are put back; the agent registers the class after every check passed.
    Loads are serialised by a lock; safe to call from a thread other than the step loop's.

    Raises :class:`KernelRejected`: "import failed: <ExcType>: msg (line N)" for any exception (syntax
    error, missing import, ``sys.exit``) while executing the module; no or several matching classes (naming
    the kernels found); a class that subclasses the wrong stage base or declares itself badly.
    Cost: that of importing the module.
    """
    want = _stage(stage)
    filename = _source_file(want, name, version)
    modname = module_name(name, version)
    with _LOAD_LOCK:
        previous = sys.modules.get(modname)
        module = types.ModuleType(modname, f"Downloaded kernel {want}/{name}@{version}")
        module.__file__ = filename
        before = {(i.stage, i.name, i.version): i.cls for i in REGISTRY}
        sys.modules[modname] = module
        ok = False
        try:
            try:
                code = compile(source, filename, "exec", dont_inherit=True)
                exec(code, module.__dict__)
            except (Exception, SystemExit) as exc:
                raise KernelRejected(f"import failed: {_describe(exc, filename)}") from None
            finally:
                _undo_registrations(before, modname)
            cls = _find_kernel(module, want, name, version)
            ok = True
            return cls
        finally:
            if not ok:
                if previous is not None:
                    sys.modules[modname] = previous
                else:
                    sys.modules.pop(modname, None)


def _find_kernel(module: types.ModuleType, stage: Stage, name: str, version: str) -> type[Kernel[Any]]:
    found = [
        obj
        for obj in vars(module).values()
        if isinstance(obj, type)
        and issubclass(obj, Kernel)
        and obj.__module__ == module.__name__
        and not inspect.isabstract(obj)
    ]
    wanted = f"{stage}/{name}@{version}"
    matches = [
        c
        for c in found
        if getattr(c, "stage", None) == stage
        and getattr(c, "name", None) == name
        and getattr(c, "version", None) == version
    ]
    if len(matches) != 1:
        listed = ", ".join(sorted(_ident(c) for c in found)) or "no kernel class"
        how = "no" if not matches else f"{len(matches)} classes for"
        raise KernelRejected(f"the module defines {how} kernel {wanted}: found {listed}")
    cls = matches[0]
    base = _STAGE_BASES[stage]
    if not issubclass(cls, base):
        raise KernelRejected(f"kernel {wanted} ({cls.__name__}) must subclass {base.__name__}")
    try:
        KernelRegistry().register(cls)  # the registry's declaration checks, on a throw-away registry
    except LinemapError as exc:
        raise KernelRejected(f"invalid kernel declaration: {exc}") from None
    return cls


# -------------------------------------------------------------------------------------- 3. conformance
def check_conformance(cls: type[Kernel[Any]], params: Mapping[str, Any] | None = None) -> None:
    """Run :func:`shared.kernels.conformance.check_kernel`; :class:`KernelRejected` listing the problems.

    The reason names at most 10 problems (and how many more there were). About 12 ``apply`` calls on at
    most 1000 points, in the calling process.
    """
    problems = check_kernel(cls, params)
    if problems:
        shown = "; ".join(problems[:10])
        more = f"; and {len(problems) - 10} more" if len(problems) > 10 else ""
        n = len(problems)
        raise KernelRejected(
            f"conformance failed for {_ident(cls)} ({n} problem{'s' if n > 1 else ''}): {shown}{more}"
        )


# ------------------------------------------------------------------------------------------ 4. dry run
@dataclass(frozen=True, slots=True)
class DryRunReport:
    """Timing of a successful dry run (milliseconds of wall-clock time in the child process).

    ``calls``: ``apply`` calls made (one per stage input); ``median_ms`` / ``max_ms``: per call;
    ``load_ms``: importing the module and constructing the kernel; ``startup_ms``: spawning the child and
    building the inputs (not the kernel's cost); ``total_ms``: the parent's wait for the run phase.
    """

    calls: int
    median_ms: float
    max_ms: float
    load_ms: float
    startup_ms: float
    total_ms: float


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
    """Import and run the kernel on real inputs in a child process, within a time and memory budget.

    The child ('spawn' start method, so nothing of the agent's state is shared) derives from each of
    ``scans`` the input the stage would see, using the default pipeline's kernels
    (:data:`DEFAULT_INPUT_KERNELS`): segmentation gets the scan; noise removal its segmented points;
    clustering the denoised points; straight-line the denoised points with their segment ids (or, for a
    kernel that ``consumes = "centroids"``, k-means centroids per segment); scan matching each scan's points
    against the previous scan's, from the odometry difference (a lone scan is matched against a moved copy
    of itself). With no scans, a simulated room scan is used. The child then caps its address space
    (``RLIMIT_AS``) at its start-up footprint plus ``memory_limit_mb`` MB, imports the module with
    :func:`load_kernel_class`, builds the kernel with ``params`` and applies it to every input, checking
    each result with the stage's result checker.

    Time: the parent waits up to ``startup_s`` (:data:`STARTUP_ALLOWANCE_S`) for the child to be ready,
    then at most ``budget_s`` seconds for the whole run phase (import + construction + every call) and
    kills the child on overrun.

    Raises :class:`KernelRejected` ("dry run: ...") for a failed import or bad declaration, rejected
    parameters, an exception in the kernel (type, message and line), an overrun ("ran longer than its X ms
    budget"), running out of memory (or the child dying), or a result that fails the stage's checks.
    Raises :class:`AgentError` when the child cannot start or build its inputs (not the kernel's fault).
    """
    want = _stage(stage)
    ctx = multiprocessing.get_context("spawn")
    receiver, sender = ctx.Pipe(duplex=False)
    proc = ctx.Process(
        target=_dry_run_child,
        args=(sender, source, str(want), name, version, dict(params or {}), list(scans), memory_limit_mb),
        name=f"dry-run {want}/{name}@{version}",
        daemon=True,
    )
    t_start = time.perf_counter()
    proc.start()
    sender.close()
    try:
        if not receiver.poll(startup_s):
            raise AgentError(
                f"dry run of {want}/{name}@{version}: the child process did not start in {startup_s} s"
            )
        first = _receive(receiver, proc, "starting")
        if first[0] != "ready":
            raise AgentError(f"dry run of {want}/{name}@{version}: could not build the inputs: {first[1]}")
        startup_ms = (time.perf_counter() - t_start) * 1e3
        t_run = time.perf_counter()
        if not receiver.poll(budget_s):
            raise KernelRejected(
                f"dry run: ran longer than its {budget_s * 1e3:.0f} ms budget"
                f" ({first[1]} input{'s' if first[1] != 1 else ''}); the process was killed"
            )
        result = _receive(receiver, proc, "running", memory_limit_mb)
        total_ms = (time.perf_counter() - t_run) * 1e3
    finally:
        if proc.is_alive():
            proc.kill()
        proc.join(timeout=10)
        receiver.close()
    if result[0] != "ok":
        raise KernelRejected(f"dry run: {result[1]}")
    times: list[float] = result[1]
    return DryRunReport(
        calls=len(times),
        median_ms=statistics.median(times) if times else 0.0,
        max_ms=max(times, default=0.0),
        load_ms=float(result[2]),
        startup_ms=startup_ms,
        total_ms=total_ms,
    )


def _receive(receiver: Connection, proc: Any, phase: str, memory_limit_mb: int | None = None) -> Any:
    """One message from the child; a child that died without a word becomes a clear error."""
    try:
        return receiver.recv()
    except (EOFError, OSError):
        proc.join(timeout=5)
        code = proc.exitcode
        how = f"was killed by signal {-code}" if code is not None and code < 0 else f"exited with code {code}"
        if memory_limit_mb is None:
            raise AgentError(f"dry run: the child process {how} while {phase}") from None
        raise KernelRejected(
            f"dry run: the kernel's process {how} without reporting (out of memory with the"
            f" {memory_limit_mb} MB limit, or a crash in native code)"
        ) from None


def _stage_inputs(stage: Stage, scans: Sequence[Scan]) -> list[tuple[tuple[Any, ...], int]]:
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


def _address_space_bytes() -> int | None:
    """This process's virtual memory size (Linux ``/proc/self/status`` VmSize), or ``None``."""
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("VmSize:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError):
        return None
    return None


def _dry_run_child(
    conn: Connection,
    source: bytes,
    stage_text: str,
    name: str,
    version: str,
    params: dict[str, Any],
    scans: list[Scan],
    memory_limit_mb: int,
) -> None:
    """The dry-run child: build inputs, cap memory, report ready, then load and run the kernel.

    Messages: ``("ready", n_inputs)`` or ``("setup-failed", why)``; then ``("ok", per-call ms, load ms)``
    or ``("rejected", reason)``.
    """
    stage = Stage(stage_text)
    try:
        inputs = _stage_inputs(stage, scans)
    except Exception as exc:
        conn.send(("setup-failed", f"{type(exc).__name__}: {exc}"))
        return
    straight = stage == Stage.STRAIGHT_LINE
    n_inputs = len(inputs) // 2 if straight else len(inputs)
    base = _address_space_bytes()
    if base is not None:
        import resource

        limit = base + memory_limit_mb * 1024 * 1024
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    conn.send(("ready", n_inputs))
    reason = _run_kernel(conn, source, stage, name, version, params, inputs, memory_limit_mb)
    if reason is not None:
        conn.send(("rejected", reason))


def _run_kernel(
    conn: Connection,
    source: bytes,
    stage: Stage,
    name: str,
    version: str,
    params: dict[str, Any],
    inputs: list[tuple[tuple[Any, ...], int]],
    memory_limit_mb: int,
) -> str | None:
    """Load and apply the kernel in the child; sends ``("ok", ...)`` and returns None, or returns why not.

    The reason is built inside the ``except`` blocks but returned after them, so the traceback (and the
    memory a runaway kernel still holds through its frames) is released before anything is sent.
    """
    filename = _source_file(stage, name, version)
    out_of_memory = f"out of memory: the kernel needed more than its {memory_limit_mb} MB limit"
    t0 = time.perf_counter()
    try:
        cls = load_kernel_class(source, stage, name, version)
        kernel: Any = cls(params)
    except KernelRejected as exc:
        return exc.reason
    except MemoryError:
        return out_of_memory
    except LinemapError as exc:
        return f"parameters rejected: {exc}"
    except Exception as exc:
        return f"constructing the kernel raised {_describe(exc, filename)}"
    load_ms = (time.perf_counter() - t0) * 1e3
    if stage == Stage.STRAIGHT_LINE:  # keep the form the kernel consumes
        form = 1 if getattr(cls, "consumes", "points") == "centroids" else 0
        inputs = inputs[form::2]
    times: list[float] = []
    for i, (args, n_in) in enumerate(inputs):
        where = f"input {i + 1} of {len(inputs)}"
        try:
            t = time.perf_counter()
            result = kernel.apply(*args)
            times.append((time.perf_counter() - t) * 1e3)
        except MemoryError:
            return f"{out_of_memory} (on {where})"
        except Exception as exc:
            return f"the kernel raised {_describe(exc, filename)} on {where}"
        problems = check_result(stage, result, n_in)
        if problems:
            shown = "; ".join(problems[:5])
            return f"result check failed on {where}: {shown}"
    conn.send(("ok", times, load_ms))
    return None
