"""Every real log in ../shared/data streams completely with the counts, stamps and odometry of SOURCE.md."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from shared.io import open_log
from shared.odometry import MINES_ROVER
from shared.types import URG04LX, Pose2D, wrap_angle

DATA = Path(__file__).resolve().parents[3] / ".." / "shared" / "data"
pytestmark = pytest.mark.skipif(not DATA.is_dir(), reason=f"real logs not found at {DATA}")


@dataclass(frozen=True)
class Expected:
    rel: str
    scans: int
    path_m: float  # odometry path length from SOURCE.md
    beams: tuple[int, ...]
    nan_share: float  # share of no-return readings (SOURCE.md)
    laser_offset_x_m: float
    odom_records: int | None = None
    nan_tol: float = 0.002
    stamps_increase: bool = True  # SOURCE.md: monotonic (the corrected logs print %g stamps: ties)


LOGS = [
    Expected("aces/aces.clf.gz", 7374, 325.0, (180,), 0.0084, 0.0, 7375),
    Expected("fr079/fr079.clf.gz", 4934, 392.0, (360,), 0.0208, -0.04, 8951),
    Expected("mit-csail/mit-csail.clf.gz", 1988, 374.0, (361,), 0.0330, 0.0, None),
    Expected("fr-clinic/fr-clinic_robotlaser.clf.gz", 6917, 1402.0, (180, 181), 0.125, 0.22, None),
    # URG: "~53-55 % of readings are 0", plus the error codes 1..19 mm
    Expected("breezyslam-urg04lx/exp1.dat.gz", 756, 46.0, (682,), 0.55, 0.145, nan_tol=0.03),
    Expected("breezyslam-urg04lx/exp2.dat.gz", 641, 44.5, (682,), 0.55, 0.145, nan_tol=0.03),
    Expected("aces/aces-corrected.log.gz", 440, 323.0, (180,), 0.0078, 0.0, stamps_increase=False),
    Expected("mit-csail/csail-corrected.log.gz", 406, 380.0, (361,), 0.0267, 0.0, stamps_increase=False),
    Expected("fr079/freiburg-079-corrected.log.gz", 4791, 422.0, (360,), 0.0209, 0.0, stamps_increase=False),
]


@pytest.mark.parametrize("exp", LOGS, ids=[e.rel.split("/")[1] for e in LOGS])
def test_log_streams_completely(exp: Expected) -> None:
    count = 0
    path_m = 0.0
    beams: set[int] = set()
    no_return = total = 0
    last_stamp = -math.inf
    prev: Pose2D | None = None
    with open_log(DATA / exp.rel) as reader:
        info = reader.info
        for scan in reader:
            count += 1
            assert scan.stamp_s > last_stamp or not exp.stamps_increase, (
                f"stamp not increasing at scan {count}"
            )
            last_stamp = scan.stamp_s
            assert scan.odometry is not None
            if prev is not None:
                path_m += math.hypot(scan.odometry.x_m - prev.x_m, scan.odometry.y_m - prev.y_m)
            prev = scan.odometry
            beams.add(scan.beam_count)
            no_return += int(np.isnan(scan.ranges_m).sum())
            total += scan.beam_count
        counts = getattr(reader, "record_counts", {})
    assert count == exp.scans
    assert path_m == pytest.approx(exp.path_m, rel=0.01)
    assert tuple(sorted(beams)) == exp.beams
    assert no_return / total == pytest.approx(exp.nan_share, abs=exp.nan_tol)
    assert info.laser_offset.x_m == pytest.approx(exp.laser_offset_x_m, abs=1e-4)
    assert info.laser_offset.y_m == pytest.approx(0.0, abs=1e-4) and info.laser_offset.theta_rad == 0.0
    if exp.odom_records is not None:
        assert counts["ODOM"] == exp.odom_records


def test_aces_first_scan_known_answer() -> None:
    with open_log(DATA / "aces" / "aces.clf.gz") as reader:
        scan = next(iter(reader))
        assert reader.info.params["simulator_num_readings"] == "180"
    assert scan.stamp_s == 70.2899
    np.testing.assert_array_equal(scan.ranges_m[:3], [46.56, 47.31, 12.51])
    assert scan.odometry == Pose2D(-0.000602, 0.012727, -1.570796)
    assert scan.angle_min_rad == -math.pi / 2 and math.degrees(scan.angle_increment_rad) == pytest.approx(1.0)


def test_fr_clinic_is_interlaced() -> None:
    starts: set[float] = set()
    with open_log(DATA / "fr-clinic" / "fr-clinic_robotlaser.clf.gz") as reader:
        for scan in reader:
            starts.add(round(math.degrees(scan.angle_min_rad), 2))
    assert sorted(starts) == [-90.0, -89.75, -89.5, -89.25]


@pytest.mark.parametrize(("name", "heading_deg"), [("exp1.dat.gz", 107.0), ("exp2.dat.gz", 79.0)])
def test_urg_logs_geometry_and_net_heading(name: str, heading_deg: float) -> None:
    heading = 0.0
    prev = None
    with open_log(DATA / "breezyslam-urg04lx" / name) as reader:
        assert reader.info.geometry == URG04LX and reader.info.robot == MINES_ROVER
        for scan in reader:
            assert scan.odometry is not None
            if prev is not None:
                heading += wrap_angle(scan.odometry.theta_rad - prev)
            prev = scan.odometry.theta_rad
            valid = scan.ranges_m[~np.isnan(scan.ranges_m)]
            assert valid.size == 0 or (valid.min() >= 0.02 and valid.max() <= 5.6)
    assert math.degrees(heading) == pytest.approx(heading_deg, abs=1.0)
