"""``make soak``: the whole reliability suite, long runs included, in under 30 minutes on 2 cores.

    .venv/bin/python -m tests.reliability.soakrun [extra pytest arguments]

Run one after the other, the suite takes ~35 minutes; so it runs in two phases:

1. side by side, two pytest processes: the kill -9 runs (``test_rel_crash_kill9.py``: agent start-ups,
   mostly CPU) and everything else but the load soak (network faults, hostile input, supply chain, auth:
   mostly waiting on sockets, timeouts and back-offs, and in-process fuzzing);
2. alone, the load soak (``test_rel_soak_load.py``), so that its latency and memory figures are the
   server's, not its neighbours';
3. the long runs outside ``tests/reliability`` (marked ``soak``, left out of ``make test`` to keep CI well
   under its limit), on two xdist workers: e.g. the half-hour patrol's accuracy and agents killed with loop
   closure on.

Each process's output goes to ``test-artifacts/reliability/soak-<part>.log`` and is printed when it ends,
with its time. Exit status: 0 when every part passed; 1 when a part failed or collected no tests (pytest's
5 never passes silently).
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
ARTIFACTS = Path(os.environ.get("LINEMAP_TEST_ARTIFACTS", ROOT / "test-artifacts")) / "reliability"
HERE = "tests/reliability"
CRASH = f"{HERE}/test_rel_crash_kill9.py"
LOAD = f"{HERE}/test_rel_soak_load.py"
PHASES: list[list[tuple[str, list[str]]]] = [
    [("crash", [CRASH]), ("rest", [HERE, f"--ignore={CRASH}", f"--ignore={LOAD}"])],
    [("load", [LOAD])],
    [("long", ["tests", f"--ignore={HERE}", "-m", "soak", "-n", "2", "--dist", "loadfile"])],
]


def _pytest(args: list[str], extra: list[str]) -> list[str]:
    return [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-rfE", *args, *extra]


def main(extra: list[str]) -> int:
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    t_all = time.monotonic()
    failed: list[str] = []
    for number, phase in enumerate(PHASES, 1):
        names = " and ".join(name for name, _ in phase)
        print(f"soak phase {number}: {names}" + (" side by side" if len(phase) > 1 else ""), flush=True)
        running = []
        for name, args in phase:
            log = ARTIFACTS / f"soak-{name}.log"
            out = log.open("wb")
            proc = subprocess.Popen(_pytest(args, extra), cwd=ROOT, stdout=out, stderr=subprocess.STDOUT)
            running.append((name, proc, out, log, time.monotonic()))
        for name, proc, out, log, t0 in running:
            code = proc.wait()
            out.close()
            took = time.monotonic() - t0
            print(f"\n===== {name}: exit {code} after {took / 60:.1f} min ({log}) =====", flush=True)
            print(log.read_text(errors="replace")[-6000:], flush=True)
            if code == 5:
                print(f"{name}: pytest collected no tests: failing", file=sys.stderr)
            if code != 0:
                failed.append(name)
    minutes = (time.monotonic() - t_all) / 60
    verdict = f"FAILED: {', '.join(failed)}" if failed else "passed"
    print(f"\nmake soak: {minutes:.1f} min in all; {verdict}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
