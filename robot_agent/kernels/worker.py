"""The kernel worker process: where a downloaded kernel's code runs, confined (docs/reliability/sandbox.md).

Started by :mod:`robot_agent.kernels.proc` as ``python -B -m robot_agent.kernels.worker ROLE FD PARENT_PID``
with an empty environment, in a fresh scratch directory, with only the socket ``FD`` open. It dies with the
agent (parent-death signal), then answers one request at a time over the socket
(:mod:`robot_agent.kernels.wire`):

``{"op": "inputs", "stage", "scans"}``     build the dry run's stage inputs with the built-in kernels
``{"op": "confine", ...}``                  warm the built-ins up, then confine itself (``sandbox.confine``)
``{"op": "load", "source", ...}``           import the module, find its kernel class (untrusted from here)
``{"op": "new", "params"}``                 construct a kernel: its id and validated parameters
``{"op": "apply", "id", "args"}``           one ``apply`` call: the result
``{"op": "dry-run", "params"}``             apply the kernel to every stage input, checking each result
``{"op": "conformance", "params"}``         the conformance battery: the problems found

Each answer is ``{"ok": value}`` or ``{"error": reason, "kind": "rejected" | "params" | "memory" |
"raised"}``. Nothing the kernel does here can reach the agent's process other than through that socket.
"""

from __future__ import annotations

import os
import socket
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

__all__ = ["main"]

_MAX_INSTANCES = 256  # constructed kernels kept per worker (by their parameters)


class _State:
    def __init__(self) -> None:
        self.cls: Any = None
        self.filename = "<kernel>"
        self.inputs: list[tuple[tuple[Any, ...], int]] = []
        self.instances: dict[str, int] = {}
        self.by_id: dict[int, Any] = {}
        self.memory_mb = 0.0


def _warm_up(stage: str, name: str) -> None:
    """Run the built-in kernels of ``stage`` named ``name`` (what a new version usually builds on) through
    the conformance battery once, before confinement: their compiled (numba) code is loaded, or compiled
    and cached, while files can still be written."""
    from shared.kernels import REGISTRY
    from shared.kernels.conformance import check_kernel

    for info in REGISTRY.list(stage):
        if info.cls.__module__.startswith("shared.") and info.name == name:
            check_kernel(info.cls)


def _failure(st: _State, exc: BaseException, what: str, where: str = "") -> dict[str, Any]:
    from robot_agent.kernels.loading import describe_error as _describe

    if isinstance(exc, MemoryError):
        limit = f"its {st.memory_mb:g} MB limit"
        on = f" (on {where})" if where else ""
        return {"error": f"out of memory: the kernel needed more than {limit}{on}", "kind": "memory"}
    on = f" on {where}" if where else ""
    return {"error": f"{what} raised {_describe(exc, st.filename)}{on}".strip(), "kind": "raised"}


def _load(st: _State, req: dict[str, Any]) -> dict[str, Any]:
    from robot_agent.errors import KernelRejected
    from robot_agent.kernels.loading import load_kernel_class
    from robot_agent.kernels.loading import source_file as _source_file

    stage, name, version = str(req["stage"]), str(req["name"]), str(req["version"])
    st.filename = _source_file(stage, name, version)
    try:
        cls = load_kernel_class(bytes.fromhex(str(req["source"])), stage, name, version)
    except KernelRejected as exc:
        return {"error": exc.reason, "kind": "rejected"}
    except MemoryError:
        return {"error": "import failed: out of memory", "kind": "memory"}
    st.cls = cls
    doc = (cls.__doc__ or "").strip()
    return {
        "ok": {
            "consumes": str(getattr(cls, "consumes", "points")),
            "doc": doc[:2000],
            "schema": cls.param_schema(),
        }
    }


def _new(st: _State, params: dict[str, Any]) -> tuple[int, dict[str, Any]]:
    import json

    from shared.errors import LinemapError

    kernel = st.cls(params)
    validated = kernel.get_params()
    if not isinstance(validated, dict):
        raise LinemapError("get_params() did not return a dict")
    key = json.dumps(validated, sort_keys=True, default=str)
    if key not in st.instances:
        if len(st.by_id) >= _MAX_INSTANCES:
            st.by_id.clear()
            st.instances.clear()
        st.instances[key] = len(st.by_id) + 1 + max(st.by_id, default=0)
        st.by_id[st.instances[key]] = kernel
    return st.instances[key], validated


def _construct(st: _State, req: dict[str, Any]) -> dict[str, Any]:
    from shared.errors import LinemapError

    try:
        kid, validated = _new(st, dict(req.get("params") or {}))
    except LinemapError as exc:
        problems = [[str(a), str(b)] for a, b in getattr(exc, "problems", None) or [("params", str(exc))]]
        return {
            "error": str(exc),
            "kind": "params",
            "kernel": str(getattr(exc, "kernel", "")),
            "problems": problems,
        }
    except (Exception, MemoryError) as exc:
        return _failure(st, exc, "constructing the kernel")
    return {"ok": {"id": kid, "params": validated}}


def _apply(st: _State, req: dict[str, Any]) -> dict[str, Any]:
    kernel = st.by_id.get(int(req["id"]))
    if kernel is None:  # dropped from the cache meanwhile: built again from its parameters
        built = _construct(st, req)
        if "error" in built:
            return built
        kernel = st.by_id[built["ok"]["id"]]
    try:
        return {"ok": kernel.apply(*req["args"])}
    except (Exception, MemoryError) as exc:
        return _failure(st, exc, "")


def _dry_run(st: _State, req: dict[str, Any]) -> dict[str, Any]:
    from shared.errors import LinemapError
    from shared.kernels import Stage
    from shared.kernels.conformance import check_result

    t0 = time.perf_counter()
    try:
        kernel = st.cls(dict(req.get("params") or {}))
    except LinemapError as exc:
        return {"error": f"parameters rejected: {exc}", "kind": "params"}
    except (Exception, MemoryError) as exc:
        return _failure(st, exc, "constructing the kernel")
    load_ms = (time.perf_counter() - t0) * 1e3
    inputs = st.inputs
    if st.cls.stage == Stage.STRAIGHT_LINE:  # keep the form the kernel consumes
        form = 1 if getattr(st.cls, "consumes", "points") == "centroids" else 0
        inputs = inputs[form::2]
    times: list[float] = []
    for i, (args, n_in) in enumerate(inputs):
        where = f"input {i + 1} of {len(inputs)}"
        try:
            t = time.perf_counter()
            result = kernel.apply(*args)
            times.append((time.perf_counter() - t) * 1e3)
        except (Exception, MemoryError) as exc:
            return _failure(st, exc, "the kernel", where)
        problems = check_result(st.cls.stage, result, n_in)
        if problems:
            return {"error": f"result check failed on {where}: {'; '.join(problems[:5])}", "kind": "raised"}
    return {"ok": {"times": times, "load_ms": load_ms}}


def _conformance(st: _State, req: dict[str, Any]) -> dict[str, Any]:
    from shared.kernels.conformance import check_kernel

    try:
        return {"ok": check_kernel(st.cls, dict(req.get("params") or {}) or None)}
    except (Exception, MemoryError) as exc:
        return _failure(st, exc, "the conformance battery")


def _inputs(st: _State, req: dict[str, Any]) -> dict[str, Any]:
    from shared.kernels import Stage
    from shared.pipeline.probe import stage_inputs

    stage = Stage(str(req["stage"]))
    try:
        st.inputs = stage_inputs(stage, list(req.get("scans") or []))
    except Exception as exc:
        return {"error": f"{type(exc).__name__}: {exc}", "kind": "setup"}
    n = len(st.inputs) // 2 if stage == Stage.STRAIGHT_LINE else len(st.inputs)
    return {"ok": n}


def _confine(st: _State, req: dict[str, Any]) -> dict[str, Any]:
    from robot_agent.kernels import sandbox

    st.memory_mb = float(req["memory_mb"])
    _warm_up(str(req["stage"]), str(req.get("name") or ""))
    cpu = req.get("cpu_s")
    report = sandbox.confine(
        Path(os.getcwd()),
        [Path(p) for p in req["packages"]],
        float(req["memory_mb"]),
        int(cpu) if cpu is not None else None,
    )
    return {"ok": report}


def _serve(sock: socket.socket) -> None:
    from robot_agent.kernels import wire

    st = _State()
    handlers: dict[str, Callable[[dict[str, Any]], dict[str, Any]]] = {
        "inputs": lambda r: _inputs(st, r),
        "confine": lambda r: _confine(st, r),
        "load": lambda r: _load(st, r),
        "new": lambda r: _construct(st, r),
        "apply": lambda r: _apply(st, r),
        "dry-run": lambda r: _dry_run(st, r),
        "conformance": lambda r: _conformance(st, r),
    }
    while True:
        try:
            req = wire.receive(sock)
        except EOFError:
            return
        handler = handlers.get(str(req.get("op"))) if isinstance(req, dict) else None
        if handler is None:
            answer: dict[str, Any] = {"error": f"unknown request {req!r:.100}", "kind": "protocol"}
        elif req["op"] in ("new", "apply", "dry-run", "conformance") and st.cls is None:
            answer = {"error": "no kernel loaded", "kind": "protocol"}
        else:
            answer = handler(req)
        try:
            wire.send(sock, answer)
        except wire.WireError as exc:  # e.g. a result of a type that may not cross
            wire.send(sock, {"error": f"apply returned what cannot be sent: {exc}", "kind": "raised"})


def main(argv: list[str]) -> None:
    """``ROLE FD PARENT_PID``: die with the parent, then serve requests on socket ``FD`` until it closes
    (``ROLE``, ``checks`` or ``service``, only names the process)."""
    from robot_agent.kernels.sandbox import die_with_parent

    fd, parent = int(argv[1]), int(argv[2])
    die_with_parent(parent)
    sys.dont_write_bytecode = True
    import numpy  # noqa: F401  (the heavy imports, before confinement)

    import shared.kernels
    import shared.kernels.conformance  # noqa: F401

    sock = socket.socket(fileno=fd)
    sock.setblocking(True)
    _serve(sock)


if __name__ == "__main__":
    main(sys.argv[1:])
