"""Which logged uploads continue a viewer's map delta by delta (server.maplog.chain_from)."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from server.maplog import LoggedUpload, chain_from


def _d(version: int, base: int) -> LoggedUpload:
    return LoggedUpload(version, base, f'{{"version":{version}}}')


def test_a_contiguous_run_is_followed_to_its_end() -> None:
    logged = [_d(3, 2), _d(4, 3), _d(5, 4)]
    assert chain_from(2, logged) == logged


def test_the_run_stops_at_a_snapshot_or_a_break() -> None:
    snap = LoggedUpload(5, None, None)
    assert chain_from(2, [_d(3, 2), _d(4, 3), snap, _d(6, 5)]) == [_d(3, 2), _d(4, 3)]
    assert chain_from(2, [_d(3, 2), _d(5, 4)]) == [_d(3, 2)]


def test_nothing_continues_a_version_the_log_no_longer_reaches() -> None:
    assert chain_from(2, [_d(9, 8), _d(10, 9)]) == []
    assert chain_from(2, []) == []


@given(st.integers(0, 1000), st.lists(st.integers(1, 5), max_size=30))
def test_every_run_is_a_prefix_and_links(start: int, steps: list[int]) -> None:
    logged, version = [], start
    for step in steps:
        logged.append(_d(version + step, version if step != 5 else version + 1))  # a step of 5 breaks
        version += step
    run = chain_from(start, logged)
    assert run == logged[: len(run)]
    base = start
    for entry in run:
        assert entry.base_version == base
        base = entry.version
