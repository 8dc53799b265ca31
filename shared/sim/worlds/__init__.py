"""The scenario suite (docs/worlds.md): kinds of world generated from a seed, with ground truth, driven with
odometry error models and driving patterns. See ``docs/worlds.md``."""

from shared.sim.worlds.suite import (
    DRIVES,
    KINDS,
    QUICK_KINDS,
    CaseRun,
    WorldKind,
    build_scene,
    drive_knots,
    simulate_case,
)

__all__ = [
    "DRIVES",
    "KINDS",
    "QUICK_KINDS",
    "CaseRun",
    "WorldKind",
    "build_scene",
    "drive_knots",
    "simulate_case",
]
