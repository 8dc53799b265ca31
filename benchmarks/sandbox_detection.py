"""How fast each kind of misbehaving downloaded kernel is detected and answered (docs/reliability/sandbox.md).

    .venv/bin/python benchmarks/sandbox_detection.py [--hang-s S] [--budget-s S]  (default: the agent's own)

For each kind, the kernel is run exactly as the agent runs it (robot_agent/kernels/dryrun.py: the checks in a
confined worker, service calls guarded in a long-lived worker) and the time is measured from the start of
the phase that meets the fault (the import, the dry run, the battery, or the service call) until the
refusal or the fallback's answer is back in the caller. Prints one line per kind with the outcome and the
reason. Start-up of the worker (a Python interpreter and numpy) is printed apart: it is not the kernel's
time and not counted in its limits.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np

from robot_agent.agent import AgentSettings
from robot_agent.errors import KernelRejected
from robot_agent.guard import guarded
from robot_agent.kernels.dryrun import load_in_worker, verify_in_worker
from shared.kernels.conformance import wall_points
from shared.kernels.noise.dbscan import Dbscan

HEAD = (
    "import numpy as np\n"
    "from shared.kernels import NoiseResult\n"
    "from shared.kernels.noise.dbscan import Dbscan\n\n"
    "{module}\n\n"
    "class Planted(Dbscan):\n    version = '{version}'\n\n"
    "    def apply(self, points):\n{body}\n"
)
PASS = "        return super().apply(points)"
FAULTS = {  # kind -> (module-level code, apply body, phase)
    "hangs at import": ("while True:\n    pass", PASS, "checks"),
    "loops on empty input": ("", "        while len(points) == 0:\n            pass\n" + PASS, "checks"),
    "opens a socket": ("", "        import socket\n        socket.socket()\n" + PASS, "checks"),
    "reads a file outside scratch": ("", "        open('/etc/hostname').read()\n" + PASS, "checks"),
    "writes a file outside scratch": (
        "",
        "        open('/tmp/linemap-was-here', 'w').write('x')\n" + PASS,
        "checks",
    ),
    "GIL-holding regex in service": (
        "",
        "        import re\n        re.match(r'(a+)+$', 'a' * 40 + 'b')",
        "service",
    ),
    "pure-Python loop in service": ("", "        while True:\n            pass", "service"),
    "huge allocation in service": ("", "        x = np.ones(1 << 40)\n" + PASS, "service"),
    "growing allocation in service": (
        "",
        "        blocks = []\n        while True:\n            blocks.append(np.ones(1 << 20))",
        "service",
    ),
    "dies in service": ("", "        import os\n        os._exit(1)", "service"),
}


def _source(i: int, module: str, body: str) -> tuple[bytes, str]:
    version = f"7.0.{i}"
    return HEAD.format(module=module, version=version, body=body).encode(), version


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--hang-s", type=float, default=AgentSettings.kernel_hang_s, help="kernel_hang_s")
    p.add_argument("--budget-s", type=float, default=AgentSettings.dry_run_budget_s, help="dry_run_budget_s")
    args = p.parse_args(argv)
    points = wall_points(600)
    Dbscan().apply(points)  # the fallback's compiled code loaded before anything is timed
    print(f"{'kind':34s} {'phase':8s} {'detected s':>10s} {'start-up s':>10s}  outcome")
    for i, (kind, (module, body, phase)) in enumerate(FAULTS.items()):
        source, version = _source(i, module, body)
        if phase == "checks":
            t0 = time.perf_counter()
            began: list[float] = []
            try:
                verify_in_worker(
                    source,
                    "noise-removal",
                    "dbscan",
                    version,
                    None,
                    [],
                    args.budget_s,
                    conformance_s=args.budget_s,
                    started=began,
                )
                outcome = "passed (!)"
            except KernelRejected as exc:
                outcome = f"rejected: {exc.reason[:100]}"
            end = time.perf_counter()
            took = end - began[0] if began else float("nan")
            startup_s = (began[0] if began else end) - t0
            print(f"{kind:34s} {phase:8s} {took:10.2f} {startup_s:10.2f}  {outcome}")
            continue
        t0 = time.perf_counter()
        cls: Any = load_in_worker(
            source, "noise-removal", "dbscan", version, memory_mb=256.0, call_s=args.hang_s, import_s=30.0
        )
        startup_s = time.perf_counter() - t0
        failures: list[str] = []
        kernel: Any = guarded(cls, Dbscan, lambda c, why: failures.append(why), 1e9)()  # noqa: B023
        t1 = time.perf_counter()
        got = kernel.apply(points)
        took = time.perf_counter() - t1
        assert np.array_equal(got.points, Dbscan().apply(points).points)  # the fallback answered
        cls.worker.close()
        outcome = f"fallback answered; rolled back: {failures[0][:80] if failures else '(no failure!)'}"
        print(f"{kind:34s} {phase:8s} {took:10.2f} {startup_s:10.2f}  {outcome}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
