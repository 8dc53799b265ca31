"""The sensor-to-host time mapping of the URG-04LX driver (pure): wrap of the 24-bit timer, the offset
from the least-delayed frame, stamps strictly increasing."""

from __future__ import annotations

import itertools

from hypothesis import given
from hypothesis import strategies as st

from robot_agent.sensors.scip import TIMESTAMP_MODULUS
from robot_agent.sensors.urg_scans import ClockMapper


@given(
    st.integers(0, TIMESTAMP_MODULUS - 1),
    st.lists(st.floats(0.0, 0.05), min_size=2, max_size=300),
    st.floats(1e6, 2e9),
)
def test_stamps_follow_the_sensor_clock_within_the_smallest_delay(
    start_ms: int, delays_s: list[float], host0_s: float
) -> None:
    """Scans every 100 ms by the sensor's clock (wrapping anywhere), received after delays of 0..50 ms:
    each stamp lies between the true host time of the scan and that plus the smallest delay so far (plus
    the bounded drift allowance), and the stamps increase."""
    mapper = ClockMapper()
    stamps, best = [], float("inf")
    for i, delay in enumerate(delays_s):
        true_s = host0_s + 0.1 * i
        best = min(best, delay)
        stamp = mapper.stamp((start_ms + 100 * i) % TIMESTAMP_MODULUS, true_s + delay)
        assert true_s - 1e-6 <= stamp <= true_s + best + 1e-3 * (0.1 * i + 0.05) + 1e-6
        stamps.append(stamp)
    assert all(b > a for a, b in itertools.pairwise(stamps))


def test_a_restarted_sensor_clock_keeps_the_stamps_increasing() -> None:
    mapper = ClockMapper()
    before = [mapper.stamp(5_000 + 100 * i, 1000.0 + 0.1 * i) for i in range(10)]
    mapper.restart()  # reconnected: the sensor's timer began again at 0
    after = [mapper.stamp(100 * i, 1001.5 + 0.1 * i) for i in range(10)]
    assert after[0] > before[-1]
    assert abs(after[-1] - after[0] - 0.9) < 1e-9
