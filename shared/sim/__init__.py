"""Simulation of the paper's artificial test environment (§6.1, Fig. 8): polygonal worlds and laser scans."""

from shared.sim.scans import RangeNoise, simulate_scan
from shared.sim.world import World, default_path, default_world

__all__ = ["RangeNoise", "World", "default_path", "default_world", "simulate_scan"]
