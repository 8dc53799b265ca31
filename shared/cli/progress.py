"""The benchmarks' progress bar: ``mapping <case>``, cases done of all, time elapsed (on stderr, gone when
done)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager

from rich.console import Console

__all__ = ["case_progress"]


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
