"""Load soak (docs/reliability.md): the server benchmark (100 robots x 2 uploads/s, long-polls, control
messages and an SSE subscriber, from this process) against one real ``linemap server`` process on a fresh
SQLite file, with the server's RSS and the upload latency sampled throughout: 0 errors, no growth trend in
memory or latency (the criteria: tests/reliability/soaktools.py). The figures go to
``test-artifacts/reliability/soak-load-{short,soak}.{json,md}`` and are printed.

The short run (25 s) is part of ``make test``; the soak (``-m soak``, ``make soak``) runs
``$LINEMAP_SOAK_SECONDS`` (default 600 s).
"""

from __future__ import annotations

import pytest

from benchmarks.server_load import Config, SetupError, measure
from tests.reliability.soaktools import (
    SECONDS_ENV,
    analyse,
    load_average,
    sample_period_s,
    soak_seconds,
    write_artifacts,
)

SHORT_S = 25.0


def run_load(
    duration_s: float, name: str, capsys: pytest.CaptureFixture[str], trends: bool = True
) -> list[str]:
    """Load the server for ``duration_s``; write and print the figures; the verdict's problems."""
    cfg = Config(duration_s=duration_s, sample_s=sample_period_s(duration_s))
    before = load_average()
    try:
        res = measure(cfg)
    except SetupError as exc:
        pytest.fail(f"the load could not run: {exc}")
    fig = analyse(cfg, res, (before, load_average()))
    title = f"Server load soak: {duration_s:g} s"
    js, md = write_artifacts(fig, name, title)
    with capsys.disabled():
        print(f"\n{fig.to_markdown(title)}(written to {md} and {js.name})")
    return fig.problems(trends)


@pytest.mark.slow
def test_server_load_short_run_has_no_errors(capsys: pytest.CaptureFixture[str]) -> None:
    """The fast part: every request answered, no error. Memory and latency trends are printed, and judged
    by the soak only (25 s on a shared machine tell no trend)."""
    assert run_load(SHORT_S, "soak-load-short", capsys, trends=False) == []


@pytest.mark.soak
def test_server_load_soak_has_no_errors_and_no_growth(capsys: pytest.CaptureFixture[str]) -> None:
    try:
        duration_s = soak_seconds()
    except ValueError as exc:
        pytest.fail(str(exc))
    assert run_load(duration_s, "soak-load-soak", capsys) == [], f"{SECONDS_ENV}={duration_s:g}"
