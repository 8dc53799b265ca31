"""The agent's side of a kernel worker process: start it, talk to it with deadlines, kill it.

:class:`KernelWorker` starts ``python -m robot_agent.kernels.worker`` (:mod:`robot_agent.kernels.worker`) with
an empty environment, in its own scratch directory, with only its end of a socket pair open, from one
long-lived spawner thread (the parent-death signal fires when the *thread* that started a child ends, so
workers are never started from a thread that may end, such as the poller). Every request has a deadline: a
worker that does not answer in time is killed (SIGKILL) and :class:`WorkerError` raised; one that dies or
answers garbage likewise. :func:`remote_class` makes a kernel class whose construction and ``apply`` run in
the worker, so the agent's registry and pipeline use it like any kernel.

Cost per ``apply``: the arguments and the result cross the socket (:mod:`robot_agent.kernels.wire`); about 0.1
ms for a scan's points (benchmarks/guard_overhead.py). Starting a worker: a Python interpreter, numpy and the
built-in kernels (about 1 s; the caller's start-up allowance covers it).
"""

from __future__ import annotations

import json
import logging
import os
import queue
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, TypeVar

from pydantic import ConfigDict

import robot_agent
import shared
from robot_agent.errors import AgentError
from robot_agent.kernels import wire
from shared.errors import KernelParameterError
from shared.kernels import Kernel, KernelParams, Stage
from shared.kernels.stages import STAGES

__all__ = ["KernelCallError", "KernelWorker", "RemoteParams", "WorkerError", "remote_class"]

log = logging.getLogger(__name__)
T = TypeVar("T")


_ROOT = Path(robot_agent.__file__).resolve().parent.parent
_PACKAGES = [str(Path(robot_agent.__file__).resolve().parent), str(Path(shared.__file__).resolve().parent)]
_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}


class WorkerError(AgentError):
    """The worker did not answer in time, died, or answered garbage; it has been killed."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


class KernelCallError(AgentError):
    """The kernel raised (or ran out of memory) in the worker, which is still alive."""

    def __init__(self, reason: str, kind: str = "raised") -> None:
        super().__init__(reason)
        self.reason, self.kind = reason, kind


class RemoteParams(KernelParams):
    """The validated parameters of a kernel that lives in a worker (validated there, carried here)."""

    model_config = ConfigDict(frozen=True, extra="allow")


# -------------------------------------------------------------------------------------------- spawner
_spawn_jobs: queue.SimpleQueue[tuple[dict[str, Any], list[Any], threading.Event]] = queue.SimpleQueue()
_spawn_lock = threading.Lock()
_spawner: list[threading.Thread] = []


def _spawn_loop() -> None:
    while True:
        kwargs, box, done = _spawn_jobs.get()
        try:
            box.append(subprocess.Popen(**kwargs))
        except BaseException as exc:  # handed back to the caller
            box.append(exc)
        done.set()


def _popen(**kwargs: Any) -> subprocess.Popen[bytes]:
    """``subprocess.Popen(**kwargs)`` run on the spawner thread, which lives as long as the process."""
    with _spawn_lock:
        if not _spawner:
            t = threading.Thread(target=_spawn_loop, name="kernel-spawner", daemon=True)
            t.start()
            _spawner.append(t)
    box: list[Any] = []
    done = threading.Event()
    _spawn_jobs.put((kwargs, box, done))
    done.wait()
    if isinstance(box[0], BaseException):
        raise box[0]
    proc: subprocess.Popen[bytes] = box[0]
    return proc


# --------------------------------------------------------------------------------------------- worker
class KernelWorker:
    """One worker process. ``label`` names it in reasons (e.g. ``"dbscan 3.0.1"``); ``role`` (``checks``
    or ``service``) is on its command line, for whoever lists processes. Thread-safe."""

    def __init__(
        self,
        label: str,
        stage: Stage | str,
        memory_mb: float,
        cpu_s: int | None,
        startup_s: float,
        role: str = "service",
    ):
        self.label = label
        self._lock = threading.Lock()
        self._dead: str | None = None
        self.scratch = Path(tempfile.mkdtemp(prefix="linemap-kernel-"))
        ours, theirs = socket.socketpair()
        self._sock = ours
        err = os.open(self.scratch / "stderr.log", os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        try:
            self.proc = _popen(
                args=[
                    sys.executable,
                    "-B",
                    "-s",
                    "-m",
                    "robot_agent.kernels.worker",
                    role,
                    str(theirs.fileno()),
                    str(os.getpid()),
                ],
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                stderr=err,
                pass_fds=(theirs.fileno(),),
                close_fds=True,
                cwd=self.scratch,
                env={
                    **_ENV,
                    "PYTHONPATH": str(_ROOT),
                    "HOME": str(self.scratch),
                    "TMPDIR": str(self.scratch),
                },
                start_new_session=True,
            )
        except OSError as exc:
            self._cleanup()
            raise AgentError(f"could not start a kernel worker process: {exc}") from None
        finally:
            os.close(err)
            theirs.close()
        self.confinement: dict[str, str] = {}
        self._stage, self._memory_mb, self._cpu_s, self._startup_s = str(stage), memory_mb, cpu_s, startup_s

    def confine(self) -> dict[str, str]:
        """Warm up and confine the worker (before anything untrusted reaches it); the layers' report."""
        got = self.request(
            {
                "op": "confine",
                "stage": self._stage,
                "name": self.label.split(" ")[0],
                "packages": _PACKAGES,
                "memory_mb": self._memory_mb,
                "cpu_s": self._cpu_s,
            },
            self._startup_s,
            "starting",
        )
        if "error" in got:
            self.close()
            raise AgentError(f"kernel worker {self.label}: confinement failed: {got['error']}")
        self.confinement = self.parse(
            got, lambda ok: {str(k): str(v) for k, v in dict(ok).items()}, "confine"
        )
        log.info("kernel worker %s (pid %d): %s", self.label, self.proc.pid, self.confinement)
        return self.confinement

    @property
    def alive(self) -> bool:
        return self._dead is None and self.proc.poll() is None

    def request(self, req: dict[str, Any], timeout_s: float, phase: str = "a call") -> dict[str, Any]:
        """Send ``req`` and wait at most ``timeout_s`` for the whole answer (``{"ok"...}``/``{"error"...}``).

        Raises :class:`WorkerError` (the worker killed first) for no answer in time, a dead worker, or an
        answer that is not of the format; the reason names ``label``, what happened and ``phase``.
        """
        with self._lock:
            if self._dead is not None:
                raise WorkerError(f"{self.label}: its worker process is gone ({self._dead})")
            deadline = time.monotonic() + timeout_s
            try:
                wire.send(self._sock, req, timeout_s)
                answer = wire.receive(self._sock, deadline)
                if not isinstance(answer, dict) or not ("ok" in answer or "error" in answer):
                    raise wire.WireError("an answer without 'ok' or 'error'")
                if "error" in answer:
                    answer["error"] = str(answer["error"])[:1000]
                return answer
            except TimeoutError:
                why = f"{self.label} did not return within {timeout_s:g} s (hung); its process was killed"
            except (EOFError, ConnectionError, OSError):
                why = f"{self.label}: its process {self._exit_text()} during {phase}{self._stderr_tail()}"
            except wire.WireError as exc:
                why = f"{self.label}: its process answered garbage ({exc}); it was killed"
            self._dead = why
            self._kill()
            raise WorkerError(why)

    def parse(self, answer: dict[str, Any], parse: Callable[[Any], T], what: str) -> T:
        """``parse(answer["ok"])``; an answer of the wrong shape kills the worker (:class:`WorkerError`)."""
        try:
            return parse(answer["ok"])
        except (KeyError, TypeError, ValueError, AttributeError, RecursionError) as exc:
            why = (
                f"{self.label}: its process answered garbage to {what} ({type(exc).__name__}); it was killed"
            )
            with self._lock:
                self._dead = why
                self._kill()
            raise WorkerError(why) from None

    def _exit_text(self) -> str:
        try:
            code = self.proc.wait(2)
        except subprocess.TimeoutExpired:
            return "stopped answering"
        if code < 0:
            return f"was killed by signal {-code} (out of memory, or a crash in native code)"
        return f"exited with code {code}"

    def _stderr_tail(self) -> str:
        try:
            text = (self.scratch / "stderr.log").read_bytes()[-4000:].decode("utf-8", "replace").strip()
        except OSError:
            return ""
        last = text.splitlines()[-1][:300] if text else ""
        return f" (last words: {last})" if last else ""

    def _kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            log.error("kernel worker %s (pid %d) survived SIGKILL for 10 s", self.label, self.proc.pid)

    def close(self) -> None:
        """Kill the worker (if still running) and remove its scratch directory."""
        with self._lock:
            if self._dead is None:
                self._dead = "closed"
            self._kill()
            self._cleanup()

    def _cleanup(self) -> None:
        self._sock.close()
        shutil.rmtree(self.scratch, ignore_errors=True)


# --------------------------------------------------------------------------------------- remote class
def remote_class(
    worker: KernelWorker, stage: Stage | str, name: str, version: str, meta: Mapping[str, Any], call_s: float
) -> type[Kernel[Any]]:
    """A kernel class for ``stage/name@version`` loaded in ``worker`` (``meta``: its ``load`` answer).

    Construction sends the parameters to the worker (validated there; an invalid set raises
    :class:`KernelParameterError` with the kernel's own message; validated sets are cached here) and
    ``apply`` runs there, each within ``call_s`` seconds: :class:`WorkerError` when the worker hung or
    died (it is killed), :class:`KernelCallError` when the kernel raised. ``close_worker()`` ends it.
    """
    want = Stage(stage)
    cache: dict[str, tuple[int, dict[str, Any]]] = {}
    label = f"{name} {version}"

    class Remote(STAGES[want].base):  # type: ignore[misc]
        Params = RemoteParams
        worker: KernelWorker

        def __init__(self, params: Any = None, /, **overrides: Any) -> None:
            values: dict[str, Any] = {}
            if isinstance(params, KernelParams):
                values.update(params.model_dump())
            elif params is not None:
                values.update(params)
            values.update(overrides)
            key = json.dumps(values, sort_keys=True, default=str)
            got = cache.get(key)
            if got is None:
                answer = worker.request({"op": "new", "params": values}, call_s, "construction")
                if "error" in answer:
                    if answer.get("kind") == "params":
                        problems = [(str(a), str(b)) for a, b in answer.get("problems") or []]
                        raise KernelParameterError(str(answer.get("kernel") or name), problems)
                    raise KernelCallError(f"{label} {answer['error']}", str(answer.get("kind")))
                got = worker.parse(answer, lambda ok: (int(ok["id"]), dict(ok["params"])), "construction")
                if len(cache) < 1024:
                    cache[key] = got
            self._remote_id = got[0]
            self._params = RemoteParams.model_validate(got[1])

        def apply(self, *args: Any) -> Any:
            req = {"op": "apply", "id": self._remote_id, "params": self.get_params(), "args": list(args)}
            answer = worker.request(req, call_s)
            if "error" in answer:
                raise KernelCallError(f"{label} {answer['error']}", str(answer.get("kind")))
            return answer["ok"]

        @classmethod
        def param_schema(cls) -> dict[str, Any]:
            return dict(meta.get("schema") or {})

        @staticmethod
        def close_worker() -> None:
            worker.close()

    Remote.name = name
    Remote.version = version
    if want == Stage.STRAIGHT_LINE:
        Remote.consumes = "centroids" if meta.get("consumes") == "centroids" else "points"
    Remote.__doc__ = str(meta.get("doc") or f"Downloaded kernel {want}/{name}@{version}.")
    Remote.__name__ = Remote.__qualname__ = f"Remote_{name.replace('-', '_')}_{version.replace('.', '_')}"
    Remote.worker = worker
    return Remote
