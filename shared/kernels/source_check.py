"""Check an untrusted kernel module's source in a child process with CPU, memory and wall-time limits.

CPython's parser answers some small inputs with a ``RecursionError`` or ``MemoryError`` after seconds and
hundreds of MB (``1+1+...`` a few hundred kB long), and a parser bug could crash the process. So
:func:`check_source_bounded` runs :func:`shared.kernels.source_limits.source_problem` in a fresh
``python -I -S`` child (no site packages, no environment, no inherited descriptors) limited to
``memory_mb`` of address space and ``timeout_s`` of CPU and wall time, and turns every outcome (a reason, a
timeout, a crash, a kill by a limit) into either success or a :class:`KernelSourceError` with a clear
reason. At most :data:`MAX_PARALLEL` children run at once; other callers wait their turn.

Cost: one interpreter start (tens of ms) plus the parse. O(len(source)).
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import threading
from pathlib import Path

from shared.errors import KernelSourceError
from shared.kernels import source_limits

__all__ = ["CHECK_MEMORY_MB", "CHECK_TIMEOUT_S", "MAX_PARALLEL", "check_source_bounded"]

#: Wall-time limit of one check (s); also its CPU limit, rounded up.
CHECK_TIMEOUT_S = 10.0
#: Address-space limit of the checking child (MB).
CHECK_MEMORY_MB = 768
#: Checks running at the same time (each may use up to ``CHECK_MEMORY_MB``).
MAX_PARALLEL = 2

_SLOTS = threading.BoundedSemaphore(MAX_PARALLEL)
_SCRIPT = str(Path(source_limits.__file__).resolve())


def check_source_bounded(
    source: bytes, timeout_s: float = CHECK_TIMEOUT_S, memory_mb: int = CHECK_MEMORY_MB
) -> None:
    """Return if ``source`` is UTF-8 Python that parses and compiles within the limits (see
    :func:`shared.kernels.source_limits.source_problem`); raise :class:`KernelSourceError` otherwise. Runs
    no code of the source. Blocks for up to ``timeout_s`` (plus the wait for a free slot)."""
    argv = [sys.executable, "-I", "-S", _SCRIPT, str(memory_mb * 2**20), str(math.ceil(timeout_s))]
    with _SLOTS:
        try:
            done = subprocess.run(
                argv, input=source, capture_output=True, timeout=timeout_s, env={}, close_fds=True
            )
        except subprocess.TimeoutExpired:
            raise KernelSourceError(_limit_reason(f"was not parsed within {timeout_s:g} s")) from None
        except OSError as exc:  # cannot start a child at all: refuse rather than parse in this process
            raise KernelSourceError(f"could not be checked: cannot start the checker ({exc})") from None
    try:
        out = json.loads(done.stdout)
        ok, reason, line = out["ok"], out.get("reason"), out.get("line")
    except (ValueError, KeyError, TypeError):
        how = f"signal {-done.returncode}" if done.returncode < 0 else f"exit code {done.returncode}"
        raise KernelSourceError(
            _limit_reason(f"stopped the checker ({how}: over {memory_mb} MB or {timeout_s:g} s of CPU)")
        ) from None
    if ok is not True:
        raise KernelSourceError(str(reason), line if isinstance(line, int) else None)


def _limit_reason(what: str) -> str:
    return (
        f"too complex to parse: it {what}; expected a module whose expressions are nested at most"
        f" {source_limits.MAX_DEPTH} deep"
    )
