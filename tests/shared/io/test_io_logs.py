"""open_log: format detection by suffix and content, gzip by magic bytes, and the file-level error paths."""

from __future__ import annotations

import dataclasses
import gzip
from pathlib import Path

import pytest

from shared.io import (
    BreezySlamReader,
    CarmenReader,
    LogError,
    LogFormatError,
    LogNotFoundError,
    UnknownLogFormatError,
    detect_format,
    open_log,
)

FLASER = "FLASER 3 1.0 2.0 3.0 0 0 0 0 0 0 {t} host 0"
DAT = " ".join(["1000000", "1", "0", "0", *["0"] * 20, *["500"] * 682, "0"])


def carmen_text(n: int = 2) -> str:
    return "# CARMEN\n" + "".join(FLASER.format(t=i) + "\n" for i in range(n))


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("aces.clf", "carmen"),
        ("aces.clf.gz", "carmen"),
        ("csail-corrected.log.gz", "carmen"),
        ("RUN.CLF", "carmen"),
        ("exp1.dat", "breezyslam"),
        ("exp1.dat.gz", "breezyslam"),
    ],
)
def test_format_by_suffix(name: str, expected: str) -> None:
    assert detect_format(Path(name)) == expected  # no file needed


@pytest.mark.parametrize(("text", "expected"), [(carmen_text(), "carmen"), (DAT + "\n", "breezyslam")])
def test_format_by_content_plain_and_gzip_without_suffix(tmp_path: Path, text: str, expected: str) -> None:
    plain = tmp_path / "log.txt"
    plain.write_text("\n" + text, encoding="utf-8")
    packed = tmp_path / "log"  # gzip, no suffix at all: found by its magic bytes
    packed.write_bytes(gzip.compress(text.encode()))
    assert detect_format(plain) == expected and detect_format(packed) == expected
    with open_log(packed) as reader:
        assert reader.info.compressed and reader.info.format == expected
        assert len(list(reader)) == (2 if expected == "carmen" else 1)


def test_open_log_returns_the_right_reader_and_format_overrides(tmp_path: Path) -> None:
    path = tmp_path / "log.dat"  # named like BreezySLAM, holds CARMEN
    path.write_text(carmen_text(), encoding="utf-8")
    with open_log(path, format="CARMEN") as reader:
        assert isinstance(reader, CarmenReader)
        assert [s.stamp_s for s in reader] == [0.0, 1.0]
    with (
        open_log(path) as wrong,
        pytest.raises(LogFormatError, match=r"log.dat line 1: BreezySLAM scan has 2 fields"),
    ):
        next(wrong)
    with open_log(tmp_path / "log.dat", "breezyslam") as reader:
        assert isinstance(reader, BreezySlamReader)


def test_unknown_format_name_and_content(tmp_path: Path) -> None:
    path = tmp_path / "notes.txt"
    path.write_text("hello world\n1 2 3\n", encoding="utf-8")
    with pytest.raises(UnknownLogFormatError, match="cannot tell the log format"):
        open_log(path)
    empty = tmp_path / "empty.txt"
    empty.write_text("", encoding="utf-8")
    with pytest.raises(UnknownLogFormatError):
        open_log(empty)
    with pytest.raises(UnknownLogFormatError, match="'netcdf': expected one of breezyslam, carmen, rosbag"):
        open_log(path, format="netcdf")


def test_missing_file_and_directory(tmp_path: Path) -> None:
    for name in ("absent.clf", "absent.clf.gz", "absent.bin"):
        with pytest.raises(LogNotFoundError, match="log file not found") as err:
            open_log(tmp_path / name)
        assert isinstance(err.value, FileNotFoundError) and isinstance(err.value, LogError)
    folder = tmp_path / "folder.clf"
    folder.mkdir()
    with pytest.raises(LogError, match="is a directory"):
        open_log(folder)


def test_gzip_line_numbers_and_truncated_gzip(tmp_path: Path) -> None:
    text = carmen_text(3) + "FLASER 3 1.0 2.0 0 0 0 0 0 0 9 host 0\n"
    path = tmp_path / "bad.clf.gz"
    path.write_bytes(gzip.compress(text.encode()))
    with (
        open_log(path) as reader,
        pytest.raises(LogFormatError, match=r"bad\.clf\.gz line 5: FLASER declares 3"),
    ):
        list(reader)
    big = "".join(FLASER.format(t=i) + "\n" for i in range(20000)).encode()
    cut = tmp_path / "cut.clf.gz"
    cut.write_bytes(gzip.compress(big)[:-2000])
    with (
        open_log(cut) as reader,
        pytest.raises(LogFormatError, match="cannot read the file from here on") as err,
    ):
        list(reader)
    assert 1 < err.value.line_no <= 20000


def test_binary_garbage_is_a_format_error(tmp_path: Path) -> None:
    path = tmp_path / "garbage.clf"
    path.write_bytes(b"\xff\xfe\x00\x81" * 100)
    with pytest.raises(LogFormatError, match=r"garbage\.clf line 1: cannot read the file"):
        open_log(path)


def test_reader_is_a_closing_context_manager_and_info_is_frozen(tmp_path: Path) -> None:
    path = tmp_path / "a.clf"
    path.write_text(carmen_text(5), encoding="utf-8")
    with open_log(path) as reader:
        it = iter(reader)
        next(it)
        info = reader.info
    assert list(reader) == []  # closed: iteration stops
    reader.close()  # idempotent
    with pytest.raises(dataclasses.FrozenInstanceError):
        info.format = "x"  # type: ignore[misc]
    assert info.path == path and info.geometry is not None and info.geometry.beam_count == 3


@pytest.mark.parametrize("packed", [False, True])
def test_progress_is_the_share_of_the_file_read(tmp_path: Path, packed: bool) -> None:
    """What ``linemap map``'s progress bar shows for a log: it grows with the scans read, from near 0 to
    1 at the end, for plain and gzip files (bytes as stored)."""
    text = ("# CARMEN\n" + "".join(FLASER.format(t=i) + "\n" for i in range(50_000))).encode()
    path = tmp_path / ("big.clf.gz" if packed else "big.clf")
    path.write_bytes(gzip.compress(text) if packed else text)
    seen: list[float] = []
    with open_log(path) as reader:
        for i, _scan in enumerate(reader):
            if i % 5000 == 0:
                share = reader.progress()
                assert share is not None
                seen.append(share)
        end = reader.progress()
    assert seen == sorted(seen) and seen[0] < 0.5 and seen[-1] > seen[0]
    assert end == 1.0
