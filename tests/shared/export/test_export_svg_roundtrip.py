"""SVG round trip: the walls of a drawn map read back in metres, and they are the walls that were drawn."""

from __future__ import annotations

import json
import re
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from shared.export import ExportIOError, SVGFormatError, read_svg_segments, render_map
from shared.export.svg_meta import SVG_METADATA_ID
from shared.pipeline.snapshot import MapSnapshot
from shared.sim import default_world
from shared.types import Pose2D

SVG = "{http://www.w3.org/2000/svg}"
_PATH = re.compile(r"M\s*(\S+)\s+(\S+)\s*L\s*(\S+)\s+(\S+)")


def _drawn_walls(path: Path) -> np.ndarray:
    """The end points of the paths in ``<g id="walls">``, in SVG points (y down)."""
    root = ET.parse(path).getroot()
    (group,) = [g for g in root.iter(f"{SVG}g") if g.get("id") == "walls"]
    rows = []
    for p in group.iter(f"{SVG}path"):
        match = _PATH.fullmatch(p.get("d", "").strip())
        assert match, p.get("d")
        rows.append([float(v) for v in match.groups()])
    return np.array(rows)


def _with(segments: np.ndarray) -> MapSnapshot:
    n = len(segments)
    return MapSnapshot(
        2, 1.0, segments, np.arange(n, dtype=np.intp) + 100, np.zeros((0, 2)), Pose2D(), np.zeros((0, 4))
    )


def test_segments_read_back_exactly(tmp_path: Path, snapshot: MapSnapshot) -> None:
    out = tmp_path / "map.svg"
    render_map(snapshot, out, walls=default_world().walls, title="room")
    back = read_svg_segments(out)
    assert np.abs(back.segments - snapshot.segments).max() <= 1e-6
    np.testing.assert_array_equal(back.segments, snapshot.segments)  # in fact bit for bit
    np.testing.assert_array_equal(back.segment_ids, snapshot.segment_ids)


def test_metadata_describes_the_drawing(tmp_path: Path, snapshot: MapSnapshot) -> None:
    """The metre coordinates map onto the drawn paths by one scale-and-flip: they are what is shown."""
    out = tmp_path / "map.svg"
    render_map(snapshot, out, walls=default_world().walls)
    drawn = _drawn_walls(out)
    assert drawn.shape == (4, 4)  # one path per map segment, in snapshot order (true walls are elsewhere)
    metres = read_svg_segments(out).segments.reshape(-1, 2)
    points = drawn.reshape(-1, 2)
    design = np.column_stack([metres, np.ones(len(metres))])
    fit, *_ = np.linalg.lstsq(design, points, rcond=None)
    assert np.abs(design @ fit - points).max() < 0.01  # SVG numbers carry 6 decimals of a point
    (sx, rx), (ry, sy) = fit[0], fit[1]
    assert abs(rx) < 1e-9 and abs(ry) < 1e-9
    assert sx > 0 and sy == pytest.approx(-sx, rel=1e-6)  # equal aspect, y up in metres is down in SVG


def test_metadata_is_not_drawn(tmp_path: Path, snapshot: MapSnapshot) -> None:
    out = tmp_path / "map.svg"
    render_map(snapshot, out)
    root = ET.parse(out).getroot()
    (meta,) = [m for m in root.findall(f"{SVG}metadata") if m.get("id") == SVG_METADATA_ID]
    assert list(meta) == [] and meta.get("data-units") == "m"  # text only: no drawable children
    doc = json.loads(meta.text or "")
    assert doc["units"] == "m" and doc["frame"] == "world" and len(doc["segments"]) == 4
    # the rest of the drawing is matplotlib's, byte for byte: removing the element leaves a valid SVG
    text = out.read_text(encoding="utf-8")
    stripped = re.sub(r'\n <metadata id="linemap-map"[^<]*</metadata>', "", text)
    assert stripped != text and "linemap-map" not in stripped
    assert ET.fromstring(stripped).tag == f"{SVG}svg"


def test_empty_map_round_trips(tmp_path: Path) -> None:
    out = tmp_path / "empty.svg"
    render_map(MapSnapshot.empty(), out, size_px=300)
    back = read_svg_segments(out)
    assert back.segments.shape == (0, 4) and back.segment_ids.shape == (0,)


@settings(max_examples=8, deadline=None)  # each example draws a figure (~0.1 s)
@given(
    segments=arrays(
        np.float64,
        st.tuples(st.integers(1, 6), st.just(4)),
        elements=st.floats(-1e4, 1e4, allow_nan=False, allow_infinity=False),
    )
)
def test_any_segments_round_trip(segments: np.ndarray) -> None:
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "m.svg"
        render_map(_with(segments), out, size_px=200)
        back = read_svg_segments(out)
    np.testing.assert_array_equal(back.segments, segments)
    np.testing.assert_array_equal(back.segment_ids, np.arange(len(segments)) + 100)


def _svg_with_metadata(body: str) -> str:
    return (
        '<svg xmlns="http://www.w3.org/2000/svg" version="1.1">'
        f'<metadata id="linemap-map">{body}</metadata></svg>'
    )


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("not xml at all <", "not well-formed XML"),
        ("<html/>", "root element is 'html': expected an SVG"),
        ('<svg xmlns="http://www.w3.org/2000/svg"/>', "no <metadata id='linemap-map'>"),
        (_svg_with_metadata("{"), "expected JSON"),
        (_svg_with_metadata('{"format": "other"}'), "format 'linemap-map'"),
        (
            _svg_with_metadata('{"format": "linemap-map", "version": 1, "units": "cm", "segments": []}'),
            "units 'cm'",
        ),
        (
            _svg_with_metadata('{"format": "linemap-map", "version": 1, "units": "m", "segments": [[1, 2]]}'),
            r"segment 0 is \[1, 2\]: expected \[id, x0, y0, x1, y1\]",
        ),
        (
            _svg_with_metadata(
                '{"format": "linemap-map", "version": 1, "units": "m", "segments": [[1.5, 0, 0, 1, 1]]}'
            ),
            "segment 0",
        ),
        (
            _svg_with_metadata(
                '{"format": "linemap-map", "version": 1, "units": "m", "segments": [[1, 0, 0, 1e999, 1]]}'
            ),
            "segment 0",
        ),
    ],
)
def test_bad_svg_is_named(tmp_path: Path, content: str, message: str) -> None:
    bad = tmp_path / "bad.svg"
    bad.write_text(content, encoding="utf-8")
    with pytest.raises(SVGFormatError, match=message):
        read_svg_segments(bad)


def test_missing_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(ExportIOError, match=r"cannot read .*nope\.svg"):
        read_svg_segments(tmp_path / "nope.svg")
