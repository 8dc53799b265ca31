"""DXF export: layers and units as the contract says, exact round trips, foreign files and errors."""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
from ezdxf.document import Drawing
from ezdxf.entities.lwpolyline import LWPolyline
from ezdxf.filemanagement import new, readfile
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from shared.errors import InvalidInputError
from shared.export import DXFFormatError, ExportIOError, encode_dxf, read_dxf, write_dxf
from shared.pipeline.snapshot import MapSnapshot
from shared.types import Pose2D


def _doc(path: Path) -> Drawing:
    doc = readfile(path)
    assert isinstance(doc, Drawing)
    return doc


def _snapshot(segments: np.ndarray, trajectory_xy: np.ndarray | None = None) -> MapSnapshot:
    n = segments.shape[0]
    traj = (
        np.zeros((0, 4))
        if trajectory_xy is None
        else np.column_stack(
            [np.arange(len(trajectory_xy), dtype=np.float64), trajectory_xy, np.zeros(len(trajectory_xy))]
        )
    )
    return MapSnapshot(
        1, 0.0, segments, np.arange(n, dtype=np.intp) * 3 + 1, np.zeros((0, 2)), Pose2D(), traj
    )


def test_layers_units_and_entities(tmp_path: Path, snapshot: MapSnapshot) -> None:
    out = tmp_path / "map.dxf"
    write_dxf(out, snapshot)
    doc = _doc(out)
    assert doc.header["$INSUNITS"] == 6 and doc.header["$MEASUREMENT"] == 1
    assert {"walls", "centroids", "trajectory"} <= {layer.dxf.name for layer in doc.layers}
    msp = doc.modelspace()
    assert len(msp.query('LINE[layer=="walls"]')) == 4
    assert len(msp.query('POINT[layer=="centroids"]')) == 3
    (poly,) = msp.query('LWPOLYLINE[layer=="trajectory"]')
    assert isinstance(poly, LWPolyline) and len(poly) == 3
    assert len(msp) == 4 + 3 + 1
    auditor = doc.audit()
    assert not auditor.has_errors, [e.message for e in auditor.errors]


def test_round_trip_is_exact(tmp_path: Path, snapshot: MapSnapshot) -> None:
    out = tmp_path / "map.dxf"
    write_dxf(out, snapshot)
    back = read_dxf(out)
    np.testing.assert_array_equal(back.segments, snapshot.segments)  # bit for bit, float64
    np.testing.assert_array_equal(back.segment_ids, snapshot.segment_ids)
    np.testing.assert_array_equal(back.centroids, snapshot.centroids)
    np.testing.assert_array_equal(back.trajectory, snapshot.trajectory[:, 1:3])


_coords = st.floats(allow_nan=False, allow_infinity=False, min_value=-1e9, max_value=1e9) | st.sampled_from(
    [0.1 + 0.2, 1 / 3, -0.0, 5e-324, 1e-300, math.pi]
)


@settings(max_examples=60, deadline=None)
@given(
    segments=arrays(np.float64, st.tuples(st.integers(0, 12), st.just(4)), elements=_coords),
    traj=arrays(np.float64, st.tuples(st.integers(2, 6), st.just(2)), elements=_coords),
)
def test_round_trip_is_exact_for_any_floats(segments: np.ndarray, traj: np.ndarray) -> None:
    snap = _snapshot(segments, traj)
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "m.dxf"
        write_dxf(out, snap)
        back = read_dxf(out)
    np.testing.assert_array_equal(back.segments, segments.reshape(-1, 4))
    np.testing.assert_array_equal(back.segment_ids, np.arange(len(segments)) * 3 + 1)
    np.testing.assert_array_equal(back.trajectory, traj)


def test_empty_map_is_a_valid_drawing(tmp_path: Path) -> None:
    out = tmp_path / "empty.dxf"
    write_dxf(out, MapSnapshot.empty())
    back = read_dxf(out)
    assert (
        back.segments.shape == (0, 4) and back.centroids.shape == (0, 2) and back.trajectory.shape == (0, 2)
    )
    assert len(_doc(out).modelspace()) == 0


def test_encode_matches_the_written_file(tmp_path: Path, snapshot: MapSnapshot) -> None:
    out = tmp_path / "m.dxf"
    write_dxf(out, snapshot)
    data = encode_dxf(snapshot)
    assert data.startswith(b"  0\nSECTION\n") and data.rstrip().endswith(b"EOF")
    assert out.read_bytes().count(b"\nLINE\n") == data.count(b"\nLINE\n") == 4


def test_foreign_dxf_in_millimetres(tmp_path: Path) -> None:
    doc = new("R2010")
    doc.header["$INSUNITS"] = 4  # millimetres
    msp = doc.modelspace()
    msp.add_line((1000.0, 0.0), (1000.0, 2500.0), dxfattribs={"layer": "WALLS"})  # layer names: any case
    msp.add_line((0.0, 0.0), (9.0, 9.0), dxfattribs={"layer": "furniture"})  # not a wall
    msp.add_circle((0.0, 0.0), 5.0, dxfattribs={"layer": "walls"})  # not a line
    out = tmp_path / "plan.dxf"
    doc.saveas(out)
    back = read_dxf(out)
    np.testing.assert_allclose(back.segments, [[1.0, 0.0, 1.0, 2.5]], rtol=0, atol=1e-12)
    assert back.segment_ids.tolist() == [-1]  # no linemap XDATA


def test_unsupported_units_are_named(tmp_path: Path) -> None:
    doc = new("R2010")
    doc.header["$INSUNITS"] = 20  # parsecs
    out = tmp_path / "far.dxf"
    doc.saveas(out)
    with pytest.raises(DXFFormatError, match=r"\$INSUNITS = 20: expected a length unit code"):
        read_dxf(out)


@pytest.mark.parametrize(
    "content",
    [b"hello world\n", b"", b"  0\nSECTION\n  2\nENTITIES\n  0\nLINE\n 10\n1.0\n", b"\xff\xfe\x00garbage"],
)
def test_not_a_dxf_is_a_format_error(tmp_path: Path, content: bytes) -> None:
    bad = tmp_path / "bad.dxf"
    bad.write_bytes(content)
    with pytest.raises(DXFFormatError, match=r"bad\.dxf: .*expected a DXF drawing"):
        read_dxf(bad)


def test_io_errors_name_the_file(tmp_path: Path, snapshot: MapSnapshot) -> None:
    with pytest.raises(ExportIOError, match=r"cannot read .*missing\.dxf"):
        read_dxf(tmp_path / "missing.dxf")
    with pytest.raises(ExportIOError, match=r"cannot write .*nodir/m\.dxf"):
        write_dxf(tmp_path / "nodir" / "m.dxf", snapshot)
    assert list(tmp_path.iterdir()) == []


def test_bad_snapshot_arrays_are_named(tmp_path: Path) -> None:
    huge_ids = MapSnapshot(
        1,
        0.0,
        np.zeros((1, 4)),
        np.array([2**40], dtype=np.intp),
        np.zeros((0, 2)),
        Pose2D(),
        np.zeros((0, 4)),
    )
    with pytest.raises(InvalidInputError, match="expected 32-bit integers"):
        write_dxf(tmp_path / "m.dxf", huge_ids)
    nan = _snapshot(np.array([[0.0, math.nan, 1.0, 1.0]]))
    with pytest.raises(InvalidInputError, match=r"snapshot\.segments row 0"):
        write_dxf(tmp_path / "m.dxf", nan)
    assert list(tmp_path.iterdir()) == []
