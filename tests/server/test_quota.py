"""The upload quota's token buckets (server.quota), on a fake clock: what passes never exceeds the burst plus
the rate times the elapsed time; a refused request passes after the wait it was told; robots are apart."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server.quota import UploadQuota
from server.settings import Settings


class Clock:
    def __init__(self) -> None:
        self.now_s = 1000.0

    def __call__(self) -> float:
        return self.now_s


RPS, BURST_R, BPS, BURST_B = 2.0, 5.0, 1000.0, 4000.0


def _quota(clock: Clock) -> UploadQuota:
    return UploadQuota(RPS, BURST_R, BPS, BURST_B, clock=clock)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.floats(0.0, 3.0), st.integers(0, 4000)), max_size=80))
def test_admitted_never_exceeds_burst_plus_rate(requests: list[tuple[float, int]]) -> None:
    clock = Clock()
    quota, start = _quota(clock), clock.now_s
    passed = passed_bytes = 0
    for dt_s, n_bytes in requests:
        clock.now_s += dt_s
        wait = quota.take(7, n_bytes)
        if wait is None:
            passed += 1
            passed_bytes += n_bytes
        else:
            assert wait > 0.0
        elapsed = clock.now_s - start
        assert passed <= BURST_R + RPS * elapsed + 1e-9
        assert passed_bytes <= BURST_B + BPS * elapsed + 1e-6


@settings(max_examples=100, deadline=None)
@given(st.integers(1, 4000), st.integers(1, 4000))
def test_refused_request_passes_after_the_wait_it_was_told(first: int, second: int) -> None:
    clock = Clock()
    quota = _quota(clock)
    assert quota.take(1, first) is None
    wait = quota.take(1, second)
    if wait is None:
        return
    clock.now_s += wait * 0.99
    assert quota.take(1, second) is not None  # not earlier
    clock.now_s += wait * 0.01 + 1e-9
    assert quota.take(1, second) is None


def test_request_rate_refuses_after_the_burst_and_robots_are_apart() -> None:
    clock = Clock()
    quota = _quota(clock)
    assert [quota.take(1, 10) for _ in range(5)] == [None] * 5
    wait = quota.take(1, 10)
    assert wait == pytest.approx(1 / RPS)
    assert quota.take(2, 10) is None  # another robot has its own buckets
    assert "2 uploads/s (burst 5)" in quota.limits() and "1000 bytes/s (burst 4000)" in quota.limits()


def test_body_larger_than_the_byte_burst_never_passes() -> None:
    assert _quota(Clock()).take(1, 4001) == float("inf")


def test_settings_refuse_a_byte_burst_below_the_largest_body() -> None:
    with pytest.raises(ValueError, match=r"upload_burst_bytes .* must be at least max_body_bytes"):
        Settings(max_body_bytes=1024 * 1024, upload_burst_bytes=512 * 1024)
