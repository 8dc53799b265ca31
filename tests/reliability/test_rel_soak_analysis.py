"""The load soak's verdict on synthetic runs (tests/reliability/soaktools.py): it passes a healthy server
(warm-up, allocator steps, a spike) and fails a leak, a latency trend, errors and a run that measured
nothing; the Theil–Sen slope is exact on lines and ignores a minority of outliers."""

from __future__ import annotations

import json
import math
import random
from collections.abc import Callable
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from benchmarks.server_load import Config, Results
from tests.reliability import soaktools
from tests.reliability.soaktools import (
    SECONDS_ENV,
    analyse,
    least_squares_slope,
    sample_period_s,
    soak_seconds,
    theil_sen_slope,
)

DURATION_S = 600.0
CFG = Config(duration_s=DURATION_S, sample_s=5.0)
MB = 1024  # kB


def healthy_rss_kb(t: float) -> float:
    """Warm-up from 60 to 100 MB over the first 200 s, then flat with 1 MB allocator steps and one spike."""
    if t < 200:
        return 60 * MB + 40 * MB * t / 200
    step = MB if int(t // 37) % 2 else 0
    spike = 20 * MB if 580 <= t < 590 else 0
    return 100 * MB + step + spike


def synthetic(
    rss_kb: Callable[[float], float] = healthy_rss_kb,
    latency_s: Callable[[float], float] = lambda t: 0.004,
    rate_hz: float = 10.0,
    errors: dict[str, int] | None = None,
    sample_s: float = 5.0,
    gap: tuple[float, float] = (0.0, 0.0),
) -> Results:
    """A run's raw results: uploads at ``rate_hz`` (none sent inside ``gap``), RSS every ``sample_s``."""
    rng = random.Random(1)
    res = Results(errors=dict(errors or {}), elapsed_s=DURATION_S)
    for k in range(int(DURATION_S * rate_hz)):
        t = k / rate_hz
        if not gap[0] <= t < gap[1]:
            res.upload_at_s.append(t)
            res.upload_s.append(latency_s(t) * rng.uniform(0.8, 1.25))
    n = int(DURATION_S / sample_s) + 1
    res.rss_samples = [(k * sample_s, round(rss_kb(k * sample_s) + rng.uniform(-200, 200))) for k in range(n)]
    return res


def test_a_healthy_server_passes_despite_warm_up_steps_and_a_spike() -> None:
    fig = analyse(CFG, synthetic())
    assert fig.problems() == []
    assert fig.errors == 0
    assert fig.uploads == 6000
    assert fig.uploads_per_s == 10.0
    assert [q.uploads for q in fig.quarters] == [1500] * 4
    assert fig.rss_start_mb == pytest.approx(60, abs=0.3)
    assert fig.rss_peak_mb == pytest.approx(121, abs=0.3)  # the spike
    assert abs(fig.rss_trend_growth_mb) < 1.0
    assert fig.rss_growth_bound_mb == pytest.approx(5.0, abs=0.1)  # 5 % of ~100 MB
    assert fig.quarters[1].p50_ms == pytest.approx(4, rel=0.15)
    assert len(fig.series) == 121
    assert sum(n for _, _, n, _ in fig.series) == 6000  # every upload in one sample window


def test_a_leak_of_2_mb_per_minute_after_warm_up_fails() -> None:
    fig = analyse(CFG, synthetic(lambda t: healthy_rss_kb(t) + max(0.0, t - 300) * 2 * MB / 60))
    [problem] = fig.problems()
    assert problem.startswith("server RSS grows")
    assert fig.rss_slope_ts_mb_per_min == pytest.approx(2.0, abs=0.1)
    assert fig.rss_trend_growth_mb == pytest.approx(10, abs=0.5)
    assert fig.rss_q4_vs_q2_pct is not None
    assert fig.rss_q4_vs_q2_pct > 5


def test_a_small_leak_within_the_bound_passes_and_reports_its_slope() -> None:
    fig = analyse(CFG, synthetic(lambda t: healthy_rss_kb(t) + max(0.0, t - 300) * 0.5 * MB / 60))
    assert fig.problems() == []
    assert fig.rss_slope_ts_mb_per_min == pytest.approx(0.5, abs=0.1)


def test_latency_that_triples_in_the_last_quarter_fails() -> None:
    fig = analyse(CFG, synthetic(latency_s=lambda t: 0.012 if t >= 450 else 0.004))
    [problem] = fig.problems()
    assert problem.startswith("upload latency grows")
    assert fig.latency_q4_p50_bound_ms is not None
    assert fig.quarters[3].p50_ms is not None
    assert fig.quarters[3].p50_ms > fig.latency_q4_p50_bound_ms


def test_a_millisecond_more_on_a_tiny_latency_is_not_a_trend() -> None:
    fig = analyse(CFG, synthetic(latency_s=lambda t: 0.0025 if t >= 450 else 0.001))
    assert fig.problems() == []
    assert fig.latency_q4_p50_bound_ms == pytest.approx(6.0, abs=0.3)  # second quarter's ~1 ms + 5 ms


def test_errors_fail_the_run_with_their_kinds() -> None:
    [problem] = analyse(CFG, synthetic(errors={"upload": 2, "sse": 1})).problems()
    assert problem == "3 errors, by kind {'upload': 2, 'sse': 1} (expected 0)"


def test_a_quarter_without_answered_uploads_fails() -> None:
    problems = analyse(CFG, synthetic(gap=(150.0, 300.0))).problems()
    assert problems == ["no upload answered in quarter(s) [2]"]


def test_too_few_memory_samples_fail() -> None:
    problems = analyse(CFG, synthetic(sample_s=400.0)).problems()
    assert problems == ["only 2 RSS samples, fewer than 3 in the second half"]


def test_least_squares_is_dragged_by_one_late_spike_theil_sen_is_not() -> None:
    t = [5.0 * k for k in range(60)]
    y = [100.0] * 59 + [140.0]
    assert theil_sen_slope(t, y) == 0.0
    assert least_squares_slope(t, y) > 0.01


@given(
    st.floats(-1e3, 1e3),
    st.floats(-1e6, 1e6),
    st.integers(2, 50),
    st.floats(0.1, 10.0),
)
def test_both_slopes_are_exact_on_a_line(slope: float, intercept: float, n: int, dt: float) -> None:
    t = [k * dt for k in range(n)]
    y = [intercept + slope * x for x in t]
    assert theil_sen_slope(t, y) == pytest.approx(slope, rel=1e-6, abs=1e-6)
    assert least_squares_slope(t, y) == pytest.approx(slope, rel=1e-6, abs=1e-6)


@given(
    st.floats(-10.0, 10.0),
    st.integers(12, 60),
    st.data(),
)
def test_theil_sen_ignores_a_fifth_of_arbitrary_outliers(slope: float, n: int, data: st.DataObject) -> None:
    t = [5.0 * k for k in range(n)]
    y = [100.0 + slope * x for x in t]
    bad = data.draw(st.lists(st.integers(0, n - 1), max_size=n // 5, unique=True))
    for i in bad:
        y[i] = data.draw(st.floats(-1e9, 1e9))
    # more than half the pairs are clean, so more than half the pairwise slopes are exactly `slope`
    assert math.comb(n - len(bad), 2) > math.comb(n, 2) / 2
    assert theil_sen_slope(t, y) == pytest.approx(slope, rel=1e-6, abs=1e-6)


def test_degenerate_inputs_have_zero_slope() -> None:
    assert theil_sen_slope([], []) == least_squares_slope([], []) == 0.0
    assert theil_sen_slope([1.0, 1.0], [0.0, 5.0]) == least_squares_slope([1.0, 1.0], [0.0, 5.0]) == 0.0


def test_soak_length_comes_from_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(SECONDS_ENV, raising=False)
    assert soak_seconds() == 600.0
    monkeypatch.setenv(SECONDS_ENV, " 1200 ")
    assert soak_seconds() == 1200.0
    for bad in ("ten", "-5", "nan", "inf", "3"):
        monkeypatch.setenv(SECONDS_ENV, bad)
        with pytest.raises(ValueError, match=rf"LINEMAP_SOAK_SECONDS='{bad}': expected a number of seconds"):
            soak_seconds()


def test_sample_period_is_a_few_seconds() -> None:
    assert [sample_period_s(d) for d in (25.0, 100.0, 600.0, 3600.0)] == [1.0, 2.5, 5.0, 5.0]


def test_artifacts_hold_the_figures(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(soaktools, "ARTIFACTS", tmp_path / "reliability")
    fig = analyse(CFG, synthetic(errors={"upload": 1}))
    js, md = soaktools.write_artifacts(fig, "soak-test", "Soak test")
    data = json.loads(js.read_text())
    assert data["errors"] == 1
    assert data["problems"] == fig.problems()
    assert [q["uploads"] for q in data["quarters"]] == [1500] * 4
    text = md.read_text()
    assert text.startswith("## Soak test\n")
    assert "| Q4 | 1500 |" in text
    assert "verdict: 1 errors" in text
