"""Simulation of the paper's artificial test environment (§6.1, Fig. 8): worlds, paths, scans and runs;
scenes that change over time and odometry error models for the scenario suite (``shared.sim.worlds``)."""

from shared.sim.errors import WorldFileError
from shared.sim.odometry_errors import ODOMETRY_MODELS, OdometryErrors, odometry_from_truth
from shared.sim.path import plan_path
from shared.sim.patrol import patrol_lap_steps, patrol_scans, scene_patrol_scans
from shared.sim.run import NO_SLIP, SimRun, SlipNoise, simulate_run, wheel_displacements_between
from shared.sim.runfiles import read_poses, write_run
from shared.sim.scans import RangeNoise, simulate_scan
from shared.sim.scene import BLACK, GLASS, MATTE, Scene, Walker, scene_raycast, simulate_scene_scan
from shared.sim.world import DEFAULT_KNOTS, World, default_path, default_world, polygon_area, polygon_walls
from shared.sim.worldfile import load_world, save_world

__all__ = [
    "BLACK",
    "DEFAULT_KNOTS",
    "GLASS",
    "MATTE",
    "NO_SLIP",
    "ODOMETRY_MODELS",
    "OdometryErrors",
    "RangeNoise",
    "Scene",
    "SimRun",
    "SlipNoise",
    "Walker",
    "World",
    "WorldFileError",
    "default_path",
    "default_world",
    "load_world",
    "odometry_from_truth",
    "patrol_lap_steps",
    "patrol_scans",
    "plan_path",
    "polygon_area",
    "polygon_walls",
    "read_poses",
    "save_world",
    "scene_patrol_scans",
    "scene_raycast",
    "simulate_run",
    "simulate_scan",
    "simulate_scene_scan",
    "wheel_displacements_between",
    "write_run",
]
