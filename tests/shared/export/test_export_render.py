"""Rendering a map to PNG and SVG with matplotlib's Agg canvas."""

from __future__ import annotations

import logging
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread

from shared.errors import InvalidInputError
from shared.export import UnsupportedFormatError, render_map, scale_bar_length_m
from shared.pipeline.snapshot import MapSnapshot
from shared.sim import default_world

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
SVG_NS = "{http://www.w3.org/2000/svg}"
ROOT = Path(__file__).resolve().parents[3]


def _png_pixels(path: Path) -> np.ndarray:
    assert path.read_bytes()[:8] == PNG_SIGNATURE
    return np.asarray(imread(path))[..., :3]


def _near(pixels: np.ndarray, hex_colour: str, tol: float = 0.06) -> int:
    rgb = np.array([int(hex_colour[i : i + 2], 16) / 255.0 for i in (1, 3, 5)])
    return int((np.abs(pixels - rgb).max(axis=-1) < tol).sum())


def test_png_has_map_colours(tmp_path: Path, snapshot: MapSnapshot) -> None:
    out = tmp_path / "map.png"
    render_map(snapshot, out, walls=default_world().walls[:4], title="room", size_px=600)
    pixels = _png_pixels(out)
    assert max(pixels.shape[:2]) == 600
    assert not np.all(pixels == 1.0)
    assert _near(pixels, "#0072B2") > 500  # map segments, thick blue
    assert _near(pixels, "#C8C8C8") > 200  # ground-truth walls, light grey
    assert _near(pixels, "#D55E00") > 20  # final pose arrow
    assert _near(pixels, "#009E73") > 20  # trajectory


def test_png_size_follows_size_px(tmp_path: Path, snapshot: MapSnapshot) -> None:
    out = tmp_path / "map.PNG"
    render_map(snapshot, out, size_px=1000)
    assert max(_png_pixels(out).shape[:2]) == 1000


def test_svg_is_valid_xml_with_paths(tmp_path: Path, snapshot: MapSnapshot) -> None:
    out = tmp_path / "map.svg"
    render_map(snapshot, out, walls=default_world().walls)
    root = ET.parse(out).getroot()
    assert root.tag == f"{SVG_NS}svg"
    assert len(root.findall(f".//{SVG_NS}path")) > 20


def test_svg_is_reproducible(tmp_path: Path, snapshot: MapSnapshot) -> None:
    a, b = tmp_path / "a.svg", tmp_path / "b.svg"
    render_map(snapshot, a)
    render_map(snapshot, b)
    assert a.read_bytes() == b.read_bytes()


@pytest.mark.parametrize("suffix", [".png", ".svg"])
def test_empty_snapshot_renders_a_frame(tmp_path: Path, suffix: str) -> None:
    out = tmp_path / f"empty{suffix}"
    render_map(MapSnapshot.empty(), out, size_px=300)
    if suffix == ".png":
        pixels = _png_pixels(out)
        assert not np.all(pixels == 1.0)  # axes frame and ticks
        assert _near(pixels, "#0072B2") == 0
    else:
        assert ET.parse(out).getroot().tag == f"{SVG_NS}svg"


def test_no_matplotlib_warnings(
    tmp_path: Path, snapshot: MapSnapshot, caplog: pytest.LogCaptureFixture
) -> None:
    with caplog.at_level(logging.WARNING):
        render_map(snapshot, tmp_path / "m.png", size_px=300)
    assert caplog.records == []


def test_bad_arguments(tmp_path: Path, snapshot: MapSnapshot) -> None:
    with pytest.raises(UnsupportedFormatError, match=r"suffix '.jpg': expected one of .png, .svg"):
        render_map(snapshot, tmp_path / "m.jpg")
    with pytest.raises(InvalidInputError, match="size_px = 10"):
        render_map(snapshot, tmp_path / "m.png", size_px=10)
    with pytest.raises(InvalidInputError, match="size_px"):
        render_map(snapshot, tmp_path / "m.png", size_px=600.0)  # type: ignore[arg-type]
    with pytest.raises(InvalidInputError, match=r"walls has shape \(2, 2\)"):
        render_map(snapshot, tmp_path / "m.png", walls=np.zeros((2, 2)))
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("span_m", "expected_m"),
    [(12.0, 2.0), (60.0, 10.0), (25.0, 5.0), (5.0, 1.0), (3.0, 0.5), (100.0, 20.0), (0.0, 1.0), (-3.0, 1.0)],
)
def test_scale_bar_length(span_m: float, expected_m: float) -> None:
    assert scale_bar_length_m(span_m) == pytest.approx(expected_m)


def test_no_pyplot_and_lazy_matplotlib(tmp_path: Path) -> None:
    code = (
        "import sys\n"
        "import shared.export\n"
        "assert 'matplotlib' not in sys.modules, 'import shared.export pulled in matplotlib'\n"
        "from shared.export import render_map\n"
        "from shared.pipeline.snapshot import MapSnapshot\n"
        f"render_map(MapSnapshot.empty(), {str(tmp_path / 'x.png')!r}, size_px=200)\n"
        "assert 'matplotlib.pyplot' not in sys.modules, 'render_map imported pyplot'\n"
        "import matplotlib\n"
        "assert matplotlib.rcParams['svg.hashsalt'] is None\n"
    )
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr
