"""Trajectory CSV: exact header, round trips, stamp strings that match relations files, reader errors."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from shared.errors import InvalidInputError
from shared.export import (
    TRAJECTORY_HEADER,
    ExportIOError,
    TrajectoryCSVError,
    read_trajectory_csv,
    write_trajectory_csv,
)
from shared.pipeline.snapshot import MapSnapshot

DATA = Path(__file__).resolve().parents[3] / ".." / "shared" / "data"


def test_header_and_rows_known_answer(tmp_path: Path, snapshot: MapSnapshot) -> None:
    out = tmp_path / "traj.csv"
    write_trajectory_csv(out, snapshot.trajectory)
    lines = out.read_text(encoding="utf-8").split("\n")
    assert lines[0] == "stamp,x,y,theta" == TRAJECTORY_HEADER
    assert lines[1] == "90.239599,1.000000000,1.000000000,0.000000000"
    assert lines[3] == "91.321399,2.000000000,1.500000000,1.570796327"
    assert lines[4] == ""  # file ends with a newline
    assert len(lines) == 5


def test_round_trip_small(tmp_path: Path, snapshot: MapSnapshot) -> None:
    out = tmp_path / "traj.csv"
    write_trajectory_csv(out, snapshot.trajectory)
    stamps, poses = read_trajectory_csv(out)
    assert stamps.shape == (3,)
    assert poses.shape == (3, 3)
    np.testing.assert_array_equal(stamps, snapshot.trajectory[:, 0])
    np.testing.assert_allclose(poses, snapshot.trajectory[:, 1:], rtol=0.0, atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(
    traj=arrays(
        np.float64,
        st.tuples(st.integers(0, 40), st.just(4)),
        elements=st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False),
    )
)
def test_round_trip_property(traj: np.ndarray) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "t.csv"
        write_trajectory_csv(out, traj)
        stamps, poses = read_trajectory_csv(out)
    assert stamps.shape == (traj.shape[0],)
    assert poses.shape == (traj.shape[0], 3)
    np.testing.assert_allclose(stamps, traj[:, 0], rtol=0.0, atol=5.1e-7)  # %.6f: microseconds
    np.testing.assert_allclose(poses, traj[:, 1:], rtol=0.0, atol=5.1e-10)  # %.9f


def test_negative_zero_and_empty(tmp_path: Path) -> None:
    out = tmp_path / "t.csv"
    write_trajectory_csv(out, np.array([[0.0, -0.0, -1e-12, 0.0]]))
    assert out.read_text(encoding="utf-8").splitlines()[1] == "0.000000,0.000000000,0.000000000,0.000000000"
    write_trajectory_csv(out, np.zeros((0, 4)))
    assert out.read_text(encoding="utf-8") == "stamp,x,y,theta\n"
    stamps, poses = read_trajectory_csv(out)
    assert stamps.shape == (0,)
    assert poses.shape == (0, 3)


@pytest.mark.parametrize("name", ["aces/aces.relations", "fr079/fr079.relations"])
def test_stamps_match_relations_strings(tmp_path: Path, name: str) -> None:
    relations = DATA / name
    if not relations.is_file():
        pytest.skip(f"{relations} is absent (real benchmark data lives in ../shared/data)")
    strings = sorted(
        {tok for line in relations.read_text().splitlines() for tok in line.split()[:2]}, key=float
    )
    traj = np.zeros((len(strings), 4))
    traj[:, 0] = [float(s) for s in strings]
    out = tmp_path / "t.csv"
    write_trajectory_csv(out, traj)
    written = [line.split(",")[0] for line in out.read_text(encoding="utf-8").splitlines()[1:]]
    assert written == strings


def test_writer_rejects_bad_arrays(tmp_path: Path) -> None:
    with pytest.raises(InvalidInputError, match=r"trajectory has shape \(3, 3\): expected \(N, 4\)"):
        write_trajectory_csv(tmp_path / "t.csv", np.zeros((3, 3)))
    with pytest.raises(InvalidInputError, match=r"trajectory row 1 .*expected finite"):
        write_trajectory_csv(tmp_path / "t.csv", np.array([[0, 0, 0, 0], [1, np.inf, 0, 0]]))
    assert not (tmp_path / "t.csv").exists()


def test_reader_tolerates_bom_crlf_spaces_and_blank_lines(tmp_path: Path) -> None:
    path = tmp_path / "t.csv"
    path.write_bytes(b"\xef\xbb\xbf stamp, x ,y,theta\r\n1.5, 2, 3 ,0.5\r\n\r\n2.5,4,5,-0.5\r\n")
    stamps, poses = read_trajectory_csv(path)
    np.testing.assert_array_equal(stamps, [1.5, 2.5])
    np.testing.assert_array_equal(poses, [[2, 3, 0.5], [4, 5, -0.5]])


@pytest.mark.parametrize(
    ("text", "pattern"),
    [
        ("", r"file is empty: expected the header line 'stamp,x,y,theta'"),
        ("stamp,x,y\n1,2,3\n", r"line 1 is 'stamp,x,y': expected the header 'stamp,x,y,theta'"),
        ("t,x,y,theta\n", r"line 1 is 't,x,y,theta'"),
        ("stamp,x,y,theta\n1,2,3,4\n1,2,3\n", r"line 3 has 3 fields: expected 4"),
        ("stamp,x,y,theta\n1,2,3,4,5\n", r"line 2 has 5 fields"),
        ("stamp,x,y,theta\n1,2,abc,4\n", r"line 2: y = 'abc': expected a finite number"),
        ("stamp,x,y,theta\n1,2,3,nan\n", r"line 2: theta = 'nan': expected a finite number"),
        ("stamp,x,y,theta\n\n1,2,3,4\n-inf,2,3,4\n", r"line 4: stamp = '-inf'"),
        ("stamp,x,y,theta\n1,,3,4\n", r"line 2: x = ''"),
    ],
)
def test_reader_errors(tmp_path: Path, text: str, pattern: str) -> None:
    path = tmp_path / "bad.csv"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(TrajectoryCSVError, match=pattern) as info:
        read_trajectory_csv(path)
    assert str(path) in str(info.value)


def test_reader_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ExportIOError, match="cannot read"):
        read_trajectory_csv(tmp_path / "absent.csv")
