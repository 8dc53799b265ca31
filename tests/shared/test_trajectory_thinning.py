"""The trajectory limit both ends apply (shared/protocol/trajectory.py): a thinned trajectory fits the
limit, keeps its newest half-limit of poses whole and its oldest pose, and stays within the limit however
many poses are appended and thinned in turn."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from shared.protocol import MAX_TRAJECTORY_POSES, thin_positions


@given(n=st.integers(0, 5000), cap=st.integers(2, 600))
def test_a_thinned_trajectory_fits_and_keeps_the_newest_half_and_the_oldest(n: int, cap: int) -> None:
    drop = thin_positions(n, cap)
    assert drop == sorted(set(drop)) and all(0 <= i < n for i in drop)
    kept = n - len(drop)
    if n <= cap:
        assert drop == []
    else:
        assert cap // 2 < kept <= cap
        assert 0 not in drop, "the oldest pose stays"
        assert min(drop) >= 1 and max(drop) < n - cap // 2, "the newest half-limit is kept whole"


@given(cap=st.integers(4, 200), batches=st.lists(st.integers(1, 80), min_size=1, max_size=60))
def test_appending_and_thinning_in_turn_stays_within_the_limit(cap: int, batches: list[int]) -> None:
    """As the server and the Robot DB do: append an upload's poses, thin; the stamps stay in order and
    the count never passes the limit, whatever the run's length."""
    kept: list[int] = []
    stamp = 0
    for size in batches:
        kept.extend(range(stamp, stamp + size))
        stamp += size
        drop = set(thin_positions(len(kept), cap))
        kept = [s for i, s in enumerate(kept) if i not in drop]
        assert len(kept) <= cap
        assert kept == sorted(kept) and kept[-1] == stamp - 1
        assert kept[0] == 0, "the run's first pose stays"


def test_the_limit_is_refused_below_two_and_bounds_a_day_at_10_hz() -> None:
    with pytest.raises(ValueError, match="at least 2"):
        thin_positions(10, 1)
    day = 864_000  # a day's poses at 10 Hz, thinned at once
    drop = thin_positions(day)
    assert MAX_TRAJECTORY_POSES // 2 < day - len(drop) <= MAX_TRAJECTORY_POSES
    assert max(drop) < day - MAX_TRAJECTORY_POSES // 2
