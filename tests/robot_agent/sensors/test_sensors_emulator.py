"""The emulated URG-04LX itself: its answers (pure model), its sampling of scans at the sensor's steps,
and ``python -m robot_agent.sensors.emulator`` as a real process a driver connects to."""

from __future__ import annotations

import itertools
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from robot_agent.sensors.scip import parse_reply
from robot_agent.sensors.scip_info import URG04LX_PARAMS, parse_state
from robot_agent.sensors.scip_scan import ScanRequest, parse_scan_reply
from robot_agent.sensors.urg import UrgDriver
from robot_agent.sensors.urg_model import UrgModel, cluster_values, sample_steps_mm
from shared.sim import SimRun
from shared.types import URG04LX, Scan
from tests.robot_agent.sensors.urgtools import SAFETY_S, mm, wait_until

ROOT = Path(__file__).resolve().parents[3]


def _status(block: bytes) -> str:
    return parse_reply(block).status


def test_the_model_answers_as_the_specification_says(sim_run: SimRun) -> None:
    model = UrgModel(sim_run.scans)
    assert _status(model.answer(b"GD0044072501")) == "10"  # laser off
    assert _status(model.answer(b"BM")) == "00" and _status(model.answer(b"BM")) == "02"
    assert _status(model.answer(b"XX")) == "0D" and _status(model.answer(b"QTX")) == "0C"
    assert _status(model.answer(b"MD0044x72501000")) == "02"
    assert _status(model.answer(b"MD0044102401000")) == "04"  # beyond the 1024 steps of a turn
    assert _status(model.answer(b"SCIP2.0")) == "0E"  # already SCIP 2.0
    tagged = parse_reply(model.answer(b"VV;hello"))
    assert tagged.echo == b"VV;hello" and tagged.status == "00"
    frame = parse_scan_reply(parse_reply(model.answer(b"GD0044072501")))
    np.testing.assert_array_equal(np.where(frame.ranges_mm >= 20, frame.ranges_mm, -1), mm(sim_run.scans[0]))


def test_the_model_timer_and_state(sim_run: SimRun) -> None:
    model = UrgModel(sim_run.scans, start_time_ms=1000)
    assert _status(model.answer(b"MD0044072501003")) == "00"
    frames = [parse_scan_reply(parse_reply(f)) for f in iter(model.next_frame, None)]
    assert [f.remaining for f in frames] == [2, 1, 0] and model.stream is None and not model.laser
    assert [f.timestamp_ms for f in frames] == [1000, 1100, 1200]  # the scans are 0.1 s apart
    assert parse_state(parse_reply(model.answer(b"II"))).time_ms == 1200
    model.answer(b"RS")
    assert parse_state(parse_reply(model.answer(b"II"))).time_ms == 0


def test_a_model_booting_in_scip_1_1_knows_only_the_switch(sim_run: SimRun) -> None:
    model = UrgModel(sim_run.scans, scip1_boot=True)
    assert model.answer(b"PP") == b"PP\nE\n\n"
    assert model.answer(b"SCIP2.0") == b"SCIP2.0\n0\n\n"
    assert _status(model.answer(b"PP")) == "00"
    model.power_on()
    assert model.answer(b"PP") == b"PP\nE\n\n"


def test_steps_sample_the_beams_of_a_urg_geometry_scan_one_to_one(sim_run: SimRun) -> None:
    steps = sample_steps_mm(sim_run.scans[3], URG04LX_PARAMS)
    assert steps.shape == (1024,)
    assert (steps[:44] == 19).all() and (steps[726:] == 19).all()  # outside AMIN..AMAX: non-measurable
    np.testing.assert_array_equal(np.where(steps[44:726] >= 20, steps[44:726], -1), mm(sim_run.scans[3]))


def test_a_coarser_scan_is_sampled_at_the_nearest_beam() -> None:
    ranges = np.arange(341, dtype=np.float64) * 0.01 + 1.0
    coarse = Scan(0.0, URG04LX.angle_min_rad, 2 * URG04LX.angle_increment_rad, 0.02, 5.6, ranges)
    steps = sample_steps_mm(coarse, URG04LX_PARAMS)
    assert steps[44] == 1000 and steps[46] == 1010 and steps[724] == 4400


@given(st.lists(st.integers(0, 6000), min_size=1, max_size=120), st.integers(0, 12))
def test_clusters_take_their_smallest_valid_range(values: list[int], cluster: int) -> None:
    step_mm = np.array(values, dtype=np.int64)
    request = ScanRequest("MD", 0, len(values) - 1, cluster)
    out = cluster_values(step_mm, request)
    g = max(cluster, 1)
    for i, got in enumerate(out.tolist()):
        group = values[i * g : (i + 1) * g]
        valid = [v for v in group if v >= 20]
        assert got == (min(valid) if valid else group[0])


def test_the_emulator_runs_as_a_process(tmp_path: Path) -> None:
    link = tmp_path / "ttyURG"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "robot_agent.sensors.emulator",
            "--world",
            "sim",
            "--link",
            str(link),
            "--rate",
            "0",
        ],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    try:
        wait_until("the emulated device", link.exists)
        with UrgDriver(str(link)) as urg:
            assert urg.parameters() == URG04LX_PARAMS
            scans = list(itertools.islice(urg.scans(), 3))
        assert [s.beam_count for s in scans] == [682, 682, 682]
    finally:
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=SAFETY_S)
    assert proc.returncode == 0, out
    assert b"URG-04LX emulator:" in out and b"Traceback" not in out
    assert not link.exists()


def test_the_emulator_process_refuses_a_bad_world(tmp_path: Path) -> None:
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "robot_agent.sensors.emulator",
            "--world",
            str(tmp_path / "no.log"),
            "--link",
            "x",
        ],
        cwd=ROOT,
        capture_output=True,
        timeout=SAFETY_S,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    assert done.returncode == 2 and b"no such file" in done.stdout and b"Traceback" not in done.stdout
