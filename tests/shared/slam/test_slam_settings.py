"""Loop-closure settings: every field validated with an error that names it; parse and as_dict round-trip."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from shared.errors import LinemapError
from shared.slam import LoopClosureSettings, LoopClosureSettingsError


def test_the_defaults_are_valid_and_round_trip() -> None:
    s = LoopClosureSettings()
    assert LoopClosureSettings.parse(s.as_dict()) == s


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("search_radius_m", -1.0),
        ("search_radius_m", math.nan),
        ("min_inlier_share", 1.5),
        ("window_rad", 4.0),
        ("keyframe_m", 0.0),
        ("submap_keyframes", 2.5),
        ("max_candidates", 0),
        ("robust_sigmas", "wide"),
        ("enabled", "yes"),
        ("inlier_m", True),
    ],
)
def test_a_bad_value_is_refused_naming_the_field(field: str, value: object) -> None:
    with pytest.raises(LoopClosureSettingsError, match=field) as info:
        LoopClosureSettings.parse({field: value})
    assert isinstance(info.value, LinemapError)
    assert "expected" in str(info.value)


def test_an_unknown_field_is_refused_with_the_known_ones_listed() -> None:
    with pytest.raises(LoopClosureSettingsError, match="search_radius") as info:
        LoopClosureSettings.parse({"serch_radius_m": 3.0})
    assert "serch_radius_m" in str(info.value)


@given(
    radius=st.floats(0.0, 100.0),
    share=st.floats(0.0, 1.0),
    submap=st.integers(0, 50),
    enabled=st.booleans(),
)
def test_valid_settings_round_trip(radius: float, share: float, submap: int, enabled: bool) -> None:
    s = LoopClosureSettings(
        search_radius_m=radius, min_inlier_share=share, submap_keyframes=submap, enabled=enabled
    )
    assert LoopClosureSettings.parse(s.as_dict()) == s
