"""Progress on stderr: the benchmarks' bar (``mapping <case>``, cases done of all, time elapsed) and
``linemap map``'s (scans, share of the input, scans/s, time left). On a terminal a bar that is gone when done;
without one (a pipe, a log file, CI) a line every few seconds instead."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from rich.console import Console

__all__ = ["LINE_PERIOD_S", "case_progress", "mapping_progress"]

#: Without a terminal, a progress line at most this often (s).
LINE_PERIOD_S = 5.0


@contextmanager
def case_progress(err: Console) -> Iterator[Callable[[str, int, int], None]]:
    """A ``note(label, done, total)`` callback drawing the bar while the block runs."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    columns = [TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn()]
    with Progress(*columns, console=err, transient=True) as progress:
        task = progress.add_task("simulating", total=None)

        def note(label: str, done: int, total: int) -> None:
            progress.update(task, description=f"mapping {label}", completed=done, total=total)

        yield note


def _eta(fraction: float | None, elapsed_s: float) -> str:
    if fraction is None or fraction <= 0.0 or fraction >= 1.0:
        return ""
    left = elapsed_s * (1.0 - fraction) / fraction
    return f", about {left:.0f} s left" if left < 120 else f", about {left / 60:.0f} min left"


@contextmanager
def mapping_progress(
    err: Console,
    name: str,
    total: int | None,
    fraction: Callable[[], float | None] | None,
    *,
    period_s: float = LINE_PERIOD_S,
) -> Iterator[Callable[[int], None]]:
    """A ``step(n)`` callback (``n`` scans mapped) drawing progress while the block runs: of ``total``
    scans when known, else of the input's ``fraction()`` read (a log's bytes, a bag's message count), else
    scans and rate alone; with the time left when it can be told. O(1) per call; redraws every 25 scans, or
    without a terminal prints a line at most every ``period_s``."""
    started = time.perf_counter()

    def share(n: int) -> float | None:
        if total:
            return min(1.0, n / total)
        return fraction() if fraction is not None else None

    if not err.is_terminal:
        last = [started]

        def line(n: int) -> None:
            now = time.perf_counter()
            if now - last[0] < period_s:
                return
            last[0] = now
            f = share(n)
            part = f", {100 * f:.0f} % of the input" if f is not None else ""
            rate = n / max(now - started, 1e-9)
            text = f"mapping {name}: {n:,} scans{part}, {rate:,.0f} scans/s{_eta(f, now - started)}"
            err.print(text, soft_wrap=True, highlight=False)

        yield line
        return

    from rich.progress import BarColumn, Progress, TaskProgressColumn, TextColumn, TimeElapsedColumn

    columns = [
        TextColumn("mapping {task.description}"),
        BarColumn(),
        TaskProgressColumn(),
        TextColumn("{task.fields[scans]}"),
        TextColumn("{task.fields[rate]}"),
        TimeElapsedColumn(),
        TextColumn("{task.fields[eta]}"),
    ]
    with Progress(*columns, console=err, transient=True) as progress:
        known = bool(total) or fraction is not None
        task = progress.add_task(name, total=1000 if known else None, scans="", rate="", eta="")

        def step(n: int) -> None:
            if n % 25:
                return
            elapsed = time.perf_counter() - started
            f = share(n)
            scans, rate = f"{n:,} scans", f"{n / max(elapsed, 1e-9):,.0f} scans/s"
            eta = _eta(f, elapsed).removeprefix(", ")
            if f is not None:
                progress.update(task, completed=1000 * f, scans=scans, rate=rate, eta=eta)
            else:
                progress.update(task, scans=scans, rate=rate)

        yield step
