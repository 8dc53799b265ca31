"""SCIP 2.0 information replies as frozen dataclasses: VV (versions), PP (parameters), II (state), and the
``SCIP2.0`` switch (pure, no I/O; C-42-03320B §2, §8.11-8.13).

Each reply's data lines read ``LABEL:value;checksum`` (see :mod:`robot_agent.sensors.scip`); parsing and
encoding are O(lines).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from robot_agent.sensors.errors import ScipError, ScipStatusError
from robot_agent.sensors.scip import SWITCH_COMMAND, Reply, encode_reply

__all__ = [
    "URG04LX_PARAMS",
    "SensorParams",
    "SensorState",
    "VersionInfo",
    "encode_info_reply",
    "parse_parameters",
    "parse_state",
    "parse_switch_reply",
    "parse_versions",
]


def _require(reply: Reply, command: str, labels: tuple[str, ...]) -> dict[str, str]:
    if reply.command != command:
        raise ScipError(f"expected a {command} reply, got one to {reply.echo!r}")
    reply.check("00")
    fields = reply.fields()
    missing = [label for label in labels if label not in fields]
    if missing:
        raise ScipError(f"{command} reply lacks {', '.join(missing)} (has {', '.join(fields) or 'nothing'})")
    return fields


@dataclass(frozen=True, slots=True)
class VersionInfo:
    """VV: vendor, product, firmware, protocol and serial number, as the sensor words them."""

    vendor: str
    product: str
    firmware: str
    protocol: str
    serial: str


def parse_versions(reply: Reply) -> VersionInfo:
    """The VV reply's fields (VEND, PROD, FIRM, PROT, SERI)."""
    f = _require(reply, "VV", ("VEND", "PROD", "FIRM", "PROT", "SERI"))
    return VersionInfo(f["VEND"], f["PROD"], f["FIRM"], f["PROT"], f["SERI"])


@dataclass(frozen=True, slots=True)
class SensorParams:
    """PP: the scanner's specification. Distances in mm and steps as the sensor gives them; the SI
    properties convert (angles counter-clockwise from the front step, REP 103)."""

    model: str
    min_range_mm: int  # DMIN
    max_range_mm: int  # DMAX
    steps_per_turn: int  # ARES
    first_step: int  # AMIN
    last_step: int  # AMAX
    front_step: int  # AFRT
    scan_rpm: int  # SCAN

    def __post_init__(self) -> None:
        if not 0 <= self.min_range_mm < self.max_range_mm:
            raise ScipError(
                f"PP DMIN {self.min_range_mm} / DMAX {self.max_range_mm} mm: expected 0 <= DMIN < DMAX"
            )
        if not 0 <= self.first_step <= self.last_step < 10000:
            raise ScipError(f"PP AMIN {self.first_step} / AMAX {self.last_step}: expected 0 <= AMIN <= AMAX")
        if self.steps_per_turn <= 0 or self.scan_rpm <= 0:
            raise ScipError(f"PP ARES {self.steps_per_turn} / SCAN {self.scan_rpm}: expected positive values")

    @property
    def angle_increment_rad(self) -> float:
        """Angle between two steps."""
        return 2.0 * math.pi / self.steps_per_turn

    def step_angle_rad(self, step: float) -> float:
        """Angle of ``step`` (fractional for the middle of a cluster)."""
        return (step - self.front_step) * self.angle_increment_rad

    @property
    def range_min_m(self) -> float:
        """DMIN in metres."""
        return self.min_range_mm / 1000.0

    @property
    def range_max_m(self) -> float:
        """DMAX in metres."""
        return self.max_range_mm / 1000.0

    @property
    def rate_hz(self) -> float:
        """Scans per second (SCAN rpm / 60)."""
        return self.scan_rpm / 60.0

    @property
    def beam_count(self) -> int:
        """Steps AMIN..AMAX."""
        return self.last_step - self.first_step + 1

    def fields(self) -> list[tuple[str, str]]:
        """The PP reply's ``(label, value)`` lines."""
        return [
            ("MODL", self.model),
            ("DMIN", str(self.min_range_mm)),
            ("DMAX", str(self.max_range_mm)),
            ("ARES", str(self.steps_per_turn)),
            ("AMIN", str(self.first_step)),
            ("AMAX", str(self.last_step)),
            ("AFRT", str(self.front_step)),
            ("SCAN", str(self.scan_rpm)),
        ]


#: The URG-04LX's PP reply (docs/design.md §3): 20..5600 mm, 1024 steps per turn, 44..725, front 384, 600 rpm.
URG04LX_PARAMS = SensorParams("URG-04LX(Hokuyo Automatic Co.,Ltd.)", 20, 5600, 1024, 44, 725, 384, 600)


def _leading_int(reply: Reply, label: str, text: str) -> int:
    digits = ""
    for ch in text.strip():
        if not "0" <= ch <= "9":  # not str.isdigit(): '²' is a digit to it, but not to int()
            break
        digits += ch
    if not digits or len(digits) > 18:
        raise ScipError(f"{reply.command} {label}:{text[:40]!r}: expected a number (at most 18 digits)")
    return int(digits)


def parse_parameters(reply: Reply) -> SensorParams:
    """The PP reply's fields (MODL, DMIN, DMAX, ARES, AMIN, AMAX, AFRT, SCAN)."""
    labels = ("MODL", "DMIN", "DMAX", "ARES", "AMIN", "AMAX", "AFRT", "SCAN")
    f = _require(reply, "PP", labels)
    nums = [_leading_int(reply, label, f[label]) for label in labels[1:]]
    return SensorParams(f["MODL"], *nums)


@dataclass(frozen=True, slots=True)
class SensorState:
    """II: the scanner's state. ``time_ms`` is its timer (TIME, hexadecimal on the URG-04LX) if readable;
    ``fields`` keeps every line as sent."""

    model: str
    laser_on: bool
    motor_speed: str
    measuring_mode: str
    bit_rate: str
    time_ms: int | None
    status: str
    fields: tuple[tuple[str, str], ...]


def parse_state(reply: Reply) -> SensorState:
    """The II reply's fields (MODL, LASR, SCSP, MESM, SBPS, TIME, STAT)."""
    f = _require(reply, "II", ("MODL", "LASR", "SCSP", "MESM", "SBPS", "TIME", "STAT"))
    try:
        time_ms: int | None = int(f["TIME"], 16)
    except ValueError:
        time_ms = None
    return SensorState(
        f["MODL"],
        f["LASR"].strip().upper().startswith("ON"),
        f["SCSP"],
        f["MESM"],
        f["SBPS"],
        time_ms,
        f["STAT"],
        tuple(f.items()),
    )


def encode_info_reply(command: str, fields: list[tuple[str, str]], tag: str = "") -> bytes:
    """A VV/PP/II reply block with status 00 (what the emulator sends)."""
    echo = (command + (";" + tag if tag else "")).encode("ascii")
    lines = [f"{label}:{value}".encode("latin-1") for label, value in fields]
    return encode_reply(echo, "00", lines, info=True)


def parse_switch_reply(reply: Reply) -> bool:
    """Whether the ``SCIP2.0`` command switched a SCIP 1.1 sensor (status ``0``: True) or found it in
    SCIP 2.0 already (``0E`` or ``00``: False); anything else is :class:`ScipStatusError`."""
    if reply.echo != SWITCH_COMMAND:
        raise ScipError(f"expected the reply to 'SCIP2.0', got one to {reply.echo!r}")
    if reply.status == "0":
        return True
    if reply.status in ("0E", "00"):
        return False
    raise ScipStatusError(
        "SCIP2.0", reply.status, "the sensor did not switch to SCIP 2.0 (a SCIP 1.1-only firmware?)"
    )
