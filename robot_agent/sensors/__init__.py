"""Sensor drivers of the robot: the URG-04LX laser and the wheel encoders."""

from robot_agent.sensors.encoders import (
    BridgeInfo,
    EncoderError,
    EncoderProtocolError,
    EncoderStats,
    OdometryReading,
    OdometrySource,
    SerialOdometry,
)
from robot_agent.sensors.errors import (
    ScipChecksumError,
    ScipError,
    ScipStatusError,
    SensorDisconnectedError,
    SensorError,
    SensorTimeoutError,
)
from robot_agent.sensors.pairing import PairingStats, paired_scans
from robot_agent.sensors.scip_info import URG04LX_PARAMS, SensorParams, SensorState, VersionInfo
from robot_agent.sensors.urg import UrgDriver, UrgStats
from robot_agent.sensors.urg_scans import ClockMapper

__all__ = [
    "URG04LX_PARAMS",
    "BridgeInfo",
    "ClockMapper",
    "EncoderError",
    "EncoderProtocolError",
    "EncoderStats",
    "OdometryReading",
    "OdometrySource",
    "PairingStats",
    "ScipChecksumError",
    "ScipError",
    "ScipStatusError",
    "SensorDisconnectedError",
    "SensorError",
    "SensorParams",
    "SensorState",
    "SensorTimeoutError",
    "SerialOdometry",
    "UrgDriver",
    "UrgStats",
    "VersionInfo",
    "paired_scans",
]
