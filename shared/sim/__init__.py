"""Simulation of the paper's artificial test environment (§6.1, Fig. 8): worlds, paths, scans and runs."""

from shared.sim.errors import WorldFileError
from shared.sim.path import plan_path
from shared.sim.patrol import patrol_lap_steps, patrol_scans
from shared.sim.run import NO_SLIP, SimRun, SlipNoise, simulate_run, wheel_displacements_between
from shared.sim.runfiles import read_poses, write_run
from shared.sim.scans import RangeNoise, simulate_scan
from shared.sim.world import DEFAULT_KNOTS, World, default_path, default_world, polygon_area, polygon_walls
from shared.sim.worldfile import load_world, save_world

__all__ = [
    "DEFAULT_KNOTS",
    "NO_SLIP",
    "RangeNoise",
    "SimRun",
    "SlipNoise",
    "World",
    "WorldFileError",
    "default_path",
    "default_world",
    "load_world",
    "patrol_lap_steps",
    "patrol_scans",
    "plan_path",
    "polygon_area",
    "polygon_walls",
    "read_poses",
    "save_world",
    "simulate_run",
    "simulate_scan",
    "wheel_displacements_between",
    "write_run",
]
