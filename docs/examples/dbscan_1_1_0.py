"""DBSCAN 1.1.0: an example kernel artifact for the dashboard and the README.

It is the built-in DBSCAN noise filter (paper §3.2) under a new version number, so installing it on a
robot, running it and rolling it back can be tried without changing the map. Sign it with
``linemap keys sign docs/examples/dbscan_1_1_0.py --key KEY.pem`` and upload it as kernel ``dbscan``,
stage ``noise-removal``, version ``1.1.0``.
"""

from shared.kernels.noise.dbscan import Dbscan


class Dbscan110(Dbscan):
    """DBSCAN, version 1.1.0 (same algorithm and parameters as 1.0.0)."""

    version = "1.1.0"
