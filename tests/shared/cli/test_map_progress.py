"""``linemap map``'s progress: a line at a time without a terminal, a bar on one; scans, the share of the
input, the rate and the time left."""

from __future__ import annotations

import io

from rich.console import Console

from shared.cli.progress import mapping_progress


def _plain() -> tuple[Console, io.StringIO]:
    out = io.StringIO()
    return Console(file=out, force_terminal=False, width=200), out


def test_without_a_terminal_lines_give_scans_share_and_rate() -> None:
    err, out = _plain()
    shares = iter([0.25, 0.5])
    with mapping_progress(err, "log x.clf", None, lambda: next(shares), period_s=0.0) as step:
        step(100)
        step(200)
    lines = out.getvalue().splitlines()
    assert len(lines) == 2
    assert lines[0].startswith("mapping log x.clf: 100 scans, 25 % of the input, ")
    assert "scans/s" in lines[0] and "left" in lines[0]
    assert lines[1].startswith("mapping log x.clf: 200 scans, 50 % of the input, ")


def test_a_known_total_counts_scans_and_an_unknown_input_gives_no_share() -> None:
    err, out = _plain()
    with mapping_progress(err, "sim", 400, None, period_s=0.0) as step:
        step(100)
    assert "100 scans, 25 % of the input" in out.getvalue()
    err, out = _plain()
    with mapping_progress(err, "bag", None, lambda: None, period_s=0.0) as step:
        step(100)
    assert "% of the input" not in out.getvalue() and "100 scans" in out.getvalue()


def test_lines_are_spaced_by_the_period() -> None:
    err, out = _plain()
    with mapping_progress(err, "log", 1000, None, period_s=3600.0) as step:
        for n in range(0, 1000, 25):
            step(n)
    assert out.getvalue() == ""  # within the first hour: none yet


def test_on_a_terminal_a_bar_is_drawn_and_gone_when_done() -> None:
    out = io.StringIO()
    err = Console(file=out, force_terminal=True, width=120)
    with mapping_progress(err, "log", None, lambda: 0.5) as step:
        for n in range(0, 200, 25):
            step(n)
    assert "mapping log" in out.getvalue()
