"""The fleet benchmark's check of what the database accepted (benchmarks/fleet_load.py ``chains``): a version
accepted twice and a delta whose base is not the version accepted before it (a lost version) are counted,
per robot; a snapshot (base null) may restart a robot's chain."""

from __future__ import annotations

import itertools

from hypothesis import given
from hypothesis import strategies as st

from benchmarks.fleet_load import Chains, chains


def test_an_unbroken_chain_counts_nothing() -> None:
    rows = [(1, 1, None), (1, 2, 1), (1, 4, 2), (2, 1, None), (2, 2, 1), (1, 5, None)]
    assert chains(rows) == Chains(uploads=6, repeated=0, broken=0)


def test_a_repeat_and_a_gap_are_counted() -> None:
    rows = [(1, 1, None), (1, 2, 1), (1, 2, 1), (1, 4, 3), (2, 1, None)]
    assert chains(rows) == Chains(uploads=5, repeated=1, broken=1)


@given(st.lists(st.integers(1, 5), min_size=1, max_size=30), st.integers(1, 3))
def test_deltas_on_their_predecessor_never_count(steps: list[int], robot: int) -> None:
    versions = list(itertools.accumulate(steps))
    rows = [(robot, versions[0], None)] + [(robot, v, p) for p, v in itertools.pairwise(versions)]
    assert chains(rows) == Chains(len(rows), 0, 0)
