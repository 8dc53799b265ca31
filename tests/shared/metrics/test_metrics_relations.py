"""Relations files and the Kümmerle et al. relation error (docs/design.md §5, data/README.md "Benchmark
metric")."""

from __future__ import annotations

import gzip
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.errors import LinemapError
from shared.metrics import (
    MetricError,
    MetricInputError,
    Relations,
    RelationsFormatError,
    parse_relations,
    read_relations,
    relation_error,
)
from shared.metrics.relations import match_stamps
from shared.types import FloatArray, Pose2D


def rel_of(t1: list[float], t2: list[float], x: list[float], y: list[float], yaw: list[float]) -> Relations:
    a = [np.array(c, dtype=np.float64) for c in (t1, t2, x, y, yaw)]
    return Relations(a[0], a[1], a[2], a[3], a[4])


DATA = Path(__file__).resolve().parents[3] / ".." / "shared" / "data"


def trajectory(n: int = 50, seed: int = 0) -> tuple[FloatArray, FloatArray]:
    rng = np.random.default_rng(seed)
    stamps = np.asarray(100.0 + 0.2 * np.arange(n), dtype=np.float64)
    theta = np.cumsum(rng.normal(0.0, 0.2, n))
    step = rng.uniform(0.05, 0.3, n)
    x = np.cumsum(step * np.cos(theta))
    y = np.cumsum(step * np.sin(theta))
    return stamps, np.stack([x, y, theta], axis=1)


def relations_from(stamps: FloatArray, poses: FloatArray, pairs: list[tuple[int, int]]) -> Relations:
    rows = []
    for i, j in pairs:
        rel = Pose2D(*poses[i]).between(Pose2D(*poses[j]))
        rows.append((stamps[i], stamps[j], rel.x_m, rel.y_m, rel.theta_rad))
    arr = np.array(rows)
    return Relations(arr[:, 0], arr[:, 1], arr[:, 2], arr[:, 3], arr[:, 4], source="test")


PAIRS = [(k, k + 1) for k in range(0, 49, 3)] + [(0, 49), (5, 40), (10, 11), (20, 35)]


# --- parsing ---------------------------------------------------------------------------------------------


def test_parse_reads_x_y_yaw_and_skips_comments() -> None:
    text = "# header\n\n1.5 2.5 0.1 -0.2 0.0 0.0 0.0 0.3\n  2.5 3.5 1e-1 2 0 0 0 -3.1  \n"
    rel = parse_relations(text)
    assert len(rel) == 2
    np.testing.assert_allclose(rel.t1_s, [1.5, 2.5])
    np.testing.assert_allclose(rel.t2_s, [2.5, 3.5])
    np.testing.assert_allclose(rel.x_m, [0.1, 0.1])
    np.testing.assert_allclose(rel.y_m, [-0.2, 2.0])
    np.testing.assert_allclose(rel.yaw_rad, [0.3, -3.1])
    assert not rel.x_m.flags.writeable


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("1 2 3 4 5 6 7", "7 fields: expected 8"),
        ("1 2 3 4 5 6 7 8 9", "9 fields"),
        ("1 2 x 4 5 6 7 8", "x = 'x' is not a number"),
        ("1 2 3 4 5 6 7 nan", "yaw = 'nan': expected a finite number"),
    ],
)
def test_malformed_line_names_the_line(line: str, message: str) -> None:
    with pytest.raises(RelationsFormatError, match=message) as info:
        parse_relations(f"1 2 0 0 0 0 0 0\n# comment\n{line}\n", source="f.relations")
    assert info.value.line_number == 3
    assert str(info.value).startswith("f.relations:3: ")
    assert isinstance(info.value, LinemapError)


def test_read_relations_file_errors(tmp_path: Path) -> None:
    with pytest.raises(MetricError, match="not found"):
        read_relations(tmp_path / "missing.relations")
    binary = tmp_path / "bin.relations"
    binary.write_bytes(b"\xff\xfe\x00\x81")
    with pytest.raises(MetricError, match="not a text relations file"):
        read_relations(binary)
    good = tmp_path / "good.relations"
    good.write_text("1 2 0.5 0 0 0 0 0\n")
    rel = read_relations(good)
    assert len(rel) == 1 and rel.source == str(good)


finite = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)


@settings(max_examples=50)
@given(st.lists(st.tuples(finite, finite, finite, finite, finite, finite, finite, finite), max_size=20))
def test_parse_round_trips(rows: list[tuple[float, ...]]) -> None:
    text = "\n".join(" ".join(repr(v) for v in row) for row in rows)
    rel = parse_relations(text)
    assert len(rel) == len(rows)
    for k, row in enumerate(rows):
        assert (rel.t1_s[k], rel.t2_s[k], rel.x_m[k], rel.y_m[k], rel.yaw_rad[k]) == (
            row[0], row[1], row[2], row[3], row[7],
        )  # fmt: skip


# --- the error ---------------------------------------------------------------------------------------------


def test_perfect_trajectory_has_zero_error() -> None:
    stamps, poses = trajectory()
    err = relation_error(stamps, poses, relations_from(stamps, poses, PAIRS))
    assert err.n_used == err.n_relations == len(PAIRS) and err.n_unmatched == 0
    assert err.trans_mean_m == pytest.approx(0.0, abs=1e-12)
    assert err.rot_mean_deg == pytest.approx(0.0, abs=1e-10)
    assert err.trans_max_m == pytest.approx(0.0, abs=1e-12)


def test_rigidly_moved_trajectory_has_zero_error() -> None:
    # relations are relative: moving the whole trajectory changes nothing
    stamps, poses = trajectory()
    rel = relations_from(stamps, poses, PAIRS)
    move = Pose2D(12.0, -3.0, 1.1)
    moved = np.array([(move @ Pose2D(*p)).as_tuple() for p in poses])
    err = relation_error(stamps, moved, rel)
    assert err.trans_mean_m == pytest.approx(0.0, abs=1e-9)
    assert err.rot_mean_deg == pytest.approx(0.0, abs=1e-8)


def test_known_translation_offset() -> None:
    # every pose from index 25 on is shifted by (0.3, 0.4) m in the world: relations that span index 25 are
    # off by exactly 0.5 m, the others by 0
    stamps, poses = trajectory()
    rel = relations_from(stamps, poses, PAIRS)
    est = poses.copy()
    est[25:, :2] += [0.3, 0.4]
    err = relation_error(stamps, est, rel)
    spans = np.array([(i < 25) != (j < 25) for i, j in PAIRS])
    np.testing.assert_allclose(err.translation_m, np.where(spans, 0.5, 0.0), atol=1e-12)
    np.testing.assert_allclose(err.rotation_deg, 0.0, atol=1e-10)
    assert err.trans_mean_m == pytest.approx(0.5 * spans.mean())
    assert err.trans_std_m == pytest.approx(np.std(np.where(spans, 0.5, 0.0)))
    assert err.trans_sq_mean_m2 == pytest.approx(0.25 * spans.mean())


def test_known_yaw_offset_at_t2() -> None:
    # rotating the pose at t2 about its own position: pure rotation error
    stamps, poses = trajectory()
    rel = relations_from(stamps, poses, [(3, 10)])
    est = poses.copy()
    est[10, 2] += math.radians(7.0)
    err = relation_error(stamps, est, rel)
    assert err.rot_mean_deg == pytest.approx(7.0)
    assert err.trans_mean_m == pytest.approx(0.0, abs=1e-12)
    assert err.summary()["rot_mean_deg"] == pytest.approx(7.0)


def test_unmatched_relations_are_counted_not_hidden() -> None:
    stamps, poses = trajectory()
    rel = relations_from(stamps, poses, PAIRS)
    bad = Relations(
        np.r_[rel.t1_s, 5000.0], np.r_[rel.t2_s, 5001.0], np.r_[rel.x_m, 1.0], np.r_[rel.y_m, 0.0],
        np.r_[rel.yaw_rad, 0.0],
    )  # fmt: skip
    err = relation_error(stamps, poses, bad)
    assert (err.n_relations, err.n_used, err.n_unmatched) == (len(PAIRS) + 1, len(PAIRS), 1)
    assert math.isnan(err.translation_m[-1])
    assert err.trans_mean_m == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(MetricError, match="none of the 1 relations"):
        relation_error(stamps, poses, rel_of([5000.0], [5001.0], [1.0], [0.0], [0.0]))


def test_stamps_match_nearest_within_tolerance_and_may_be_unsorted() -> None:
    stamps, poses = trajectory()
    rel = relations_from(stamps, poses, PAIRS)
    # relation stamps printed with 5 decimals while the log has 6 (MIT CSAIL)
    jittered = Relations(rel.t1_s + 4e-6, rel.t2_s - 4e-6, rel.x_m, rel.y_m, rel.yaw_rad)
    order = np.random.default_rng(3).permutation(len(stamps))
    err = relation_error(stamps[order], poses[order], jittered)
    assert err.n_used == len(PAIRS) and err.trans_mean_m == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(MetricError):
        relation_error(stamps, poses, jittered, stamp_tolerance_s=1e-6)


def test_match_stamps() -> None:
    t = np.array([3.0, 1.0, 2.0])
    np.testing.assert_array_equal(match_stamps(t, np.array([1.0004, 2.6, 3.0, 0.0]), 0.001), [1, -1, 0, -1])
    np.testing.assert_array_equal(match_stamps(np.array([5.0]), np.array([5.0, 6.0]), 0.1), [0, -1])
    np.testing.assert_array_equal(match_stamps(np.zeros(0), np.array([5.0]), 0.1), [-1])


def test_bad_trajectory_input() -> None:
    rel = rel_of([1.0], [2.0], [0.0], [0.0], [0.0])
    with pytest.raises(MetricInputError, match=r"poses has shape \(2, 2\)"):
        relation_error([1.0, 2.0], np.zeros((2, 2)), rel)
    with pytest.raises(MetricInputError, match=r"stamps\[1\]"):
        relation_error([1.0, np.nan], np.zeros((2, 3)), rel)
    with pytest.raises(MetricInputError, match="stamp_tolerance_s"):
        relation_error([1.0, 2.0], np.zeros((2, 3)), rel, stamp_tolerance_s=-1.0)
    with pytest.raises(MetricError, match=r"Relations\.x_m has 2 values"):
        rel_of([1.0], [2.0], [0.0, 1.0], [0.0], [0.0])


# --- the real benchmark logs: raw odometry against the relations ------------------------------------------


def flaser_odometry(path: Path) -> tuple[FloatArray, FloatArray]:
    """``ipc_timestamp`` and ``odom_x odom_y odom_theta`` of every FLASER line (see the SOURCE.md files)."""
    stamps: list[float] = []
    poses: list[tuple[float, float, float]] = []
    with gzip.open(path, "rt") as f:
        for line in f:
            if not line.startswith("FLASER "):
                continue
            fields = line.split()
            n = int(fields[1])
            base = 2 + n  # after the ranges: x y theta odom_x odom_y odom_theta ipc_timestamp ...
            poses.append((float(fields[base + 3]), float(fields[base + 4]), float(fields[base + 5])))
            stamps.append(float(fields[base + 6]))
    return np.array(stamps), np.array(poses)


@pytest.mark.parametrize(
    ("folder", "log", "relations", "mean_m", "std_m"),
    [
        ("aces", "aces.clf.gz", "aces.relations", 0.549, 2.674),
        ("fr079", "fr079.clf.gz", "fr079.relations", 6.504, 13.664),
        ("mit-csail", "mit-csail.clf.gz", "mit-csail.relations", 1.681, 5.292),
    ],
)
def test_log_odometry_baselines(folder: str, log: str, relations: str, mean_m: float, std_m: float) -> None:
    log_path, rel_path = DATA / folder / log, DATA / folder / relations
    if not (log_path.exists() and rel_path.exists()):
        pytest.skip(f"benchmark data not found at {DATA / folder} (the ../shared/data folder is absent)")
    stamps, poses = flaser_odometry(log_path)
    err = relation_error(stamps, poses, read_relations(rel_path))
    assert err.n_unmatched == 0
    assert err.trans_mean_m == pytest.approx(mean_m, abs=1e-3)
    assert err.trans_std_m == pytest.approx(std_m, abs=1e-3)
